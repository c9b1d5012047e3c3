"""A run's configuration is validated as a whole, whoever builds it (the CLI or a script)."""

from pathlib import Path

import pytest
from pydantic import ValidationError

from analytic.config import RunConfig
from analytic.run import TuningRun
from schemas.wire import describe


def test_generations_and_evaluations_exclude_each_other() -> None:
    with pytest.raises(ValidationError) as raised:
        RunConfig(generations=3, evaluations=90)
    assert describe(raised.value) == "generations and evaluations exclude each other"


def test_the_termination_follows_the_config() -> None:
    assert RunConfig(generations=3).termination_text == "3 generations"
    assert RunConfig(evaluations=90).termination.evaluations == 90
    assert RunConfig().termination_text.startswith("until converged")
    assert RunConfig().mode == "specific"


def test_a_run_refuses_a_config_that_skipped_validation(tmp_path: Path) -> None:
    both = RunConfig(generations=3).model_copy(update={"evaluations": 90})  # no validation
    with pytest.raises(ValidationError, match="exclude each other"):
        TuningRun.create(tmp_path / "run", both)
    assert not (tmp_path / "run").exists()
