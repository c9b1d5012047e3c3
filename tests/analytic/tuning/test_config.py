"""A run's configuration is validated as a whole, whoever builds it (the CLI or a script)."""

from pathlib import Path

import pytest
from pydantic import ValidationError

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.analytic.view.reports import run_setup
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.wire import describe


def test_generations_and_evaluations_exclude_each_other() -> None:
    with pytest.raises(ValidationError) as raised:
        RunConfig(generations=3, evaluations=90)
    assert describe(raised.value) == "generations and evaluations exclude each other"


def test_the_termination_follows_the_config() -> None:
    assert RunConfig(generations=3).termination_text == "3 generations"
    assert RunConfig(generations=1).termination_text == "1 generation"
    assert RunConfig(evaluations=90).termination.evaluations == 90
    assert RunConfig().termination_text.startswith("until converged")
    assert RunConfig().mode == "specific"


def test_a_run_refuses_a_config_that_skipped_validation(tmp_path: Path) -> None:
    both = RunConfig(generations=3).model_copy(update={"evaluations": 90})  # no validation
    with pytest.raises(ValidationError, match="exclude each other"):
        TuningRun.create(tmp_path / "run", both)
    assert not (tmp_path / "run").exists()


def test_objective_weights_need_one_positive_pair_per_trajectory() -> None:
    two = (TrajectorySpec(), TrajectorySpec(kind="pyramid"))
    config = RunConfig(trajectories=two, objective_weights=((0.7, 0.9), (0.3, 0.1)))
    assert RunConfig.model_validate_json(config.model_dump_json()) == config
    assert "weights f_acc 0.70 / 0.30, f_t 0.90 / 0.10" in run_setup(config)[0]
    with pytest.raises(ValidationError, match="1 pairs for 2 trajectories"):
        RunConfig(trajectories=two, objective_weights=((1.0, 1.0),))
    for bad in ((0.0, 1.0), (1.0, float("inf")), (-1.0, 1.0)):
        with pytest.raises(ValidationError):
            RunConfig(trajectories=two, objective_weights=(bad, (1.0, 1.0)))
