"""`tune`, the one-call face of the analytic layer, as the README shows it."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from gainfarm.analytic import FarmOptions, InProcessEvaluator, RunConfig, read_run, tune
from gainfarm.analytic.compose import CannotStart, balanced
from gainfarm.analytic.evaluators.farm import FarmUnavailable
from gainfarm.analytic.evaluators.local import free_port
from gainfarm.cli import values
from gainfarm.models import resolve
from gainfarm.schemas import TrajectorySpec
from tests.analytic.toy import toy_scores

README = Path(__file__).parents[3] / "README.md"
CONFIG = RunConfig(
    pop=6, seed=1, trajectories=(TrajectorySpec(kind="fourier", duration=0.5),), generations=2
)


@pytest.mark.slow
def test_the_readme_example_runs(tmp_path: Path) -> None:
    [example] = [
        block
        for block in re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)
        if "tune(" in block
    ]
    run = subprocess.run(
        [sys.executable, "-c", example], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    assert 1 <= len(lines) <= 3
    assert all(re.fullmatch(r"\d+\.\d\d mm, \S+ \(N·m\)², Kp \d+", line) for line in lines)
    record = read_run(tmp_path / "runs" / "example")
    assert record.stopped == "2 generations" and len(record.front) >= len(lines)
    assert (tmp_path / "runs" / "example" / "report.md").is_file()


def test_tune_resumes_or_returns_a_run_and_refuses_another_configuration(tmp_path: Path) -> None:
    evaluator = InProcessEvaluator(scorer=toy_scores)
    first = tune(CONFIG, tmp_path / "run", evaluator=evaluator)
    assert first.finished and (tmp_path / "run" / "pareto.png").is_file()
    front = (tmp_path / "run" / "front.csv").read_bytes()
    again = tune(CONFIG, tmp_path / "run", evaluator=evaluator)  # finished: nothing runs
    assert again.state.evolution.evaluations == 12
    longer = CONFIG.model_copy(update={"generations": 3})
    with pytest.raises(ValueError, match="another configuration"):
        tune(longer, tmp_path / "run", evaluator=evaluator)
    assert (tmp_path / "run" / "front.csv").read_bytes() == front


# --- the one composition root: what `analytic start` decides before a run, `tune` decides too ---


def test_tune_balances_a_generic_run_by_the_default_gains_real_episodes(tmp_path: Path) -> None:
    generic = CONFIG.model_copy(
        update={
            "trajectories": (
                TrajectorySpec(kind="fourier", duration=0.5),
                TrajectorySpec(kind="fourier", duration=0.5, seed=1),
            )
        }
    )
    run = tune(generic, tmp_path / "run", evaluator=InProcessEvaluator(scorer=toy_scores))
    weights = run.config.objective_weights
    assert weights is not None and len(weights) == 2
    assert weights == balanced(generic).objective_weights  # deterministic: the same episodes
    # Asked again as it was asked, the run is found, not refused as another configuration.
    assert tune(generic, tmp_path / "run").config == run.config
    plain = tune(
        generic.model_copy(update={"balance": False}), tmp_path / "plain", evaluator=evaluator()
    )
    assert plain.config.objective_weights is None


def evaluator() -> InProcessEvaluator:
    return InProcessEvaluator(scorer=toy_scores)


@pytest.mark.parametrize(
    ("update", "part"),
    [
        ({"trajectories": (TrajectorySpec(center=(2.0, 0.0, 0.4), duration=3.0),)}, "placement"),
        ({"trajectories": (TrajectorySpec(kind="pyramid", duration=0.5),)}, "duration"),
    ],
)
def test_tune_refuses_a_trajectory_the_arm_cannot_follow_before_writing_anything(
    tmp_path: Path, update: dict, part: str
) -> None:
    with pytest.raises(CannotStart) as refused:
        tune(CONFIG.model_copy(update=update), tmp_path / "run", evaluator=evaluator())
    assert refused.value.part == part
    assert list(tmp_path.iterdir()) == []


def test_tune_claims_its_directory_and_leaves_nothing_if_the_farm_cannot_be_had(
    tmp_path: Path,
) -> None:
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(CannotStart, match="is not empty") as refused:
        tune(CONFIG, mine, evaluator=evaluator())
    assert refused.value.part == "out" and [p.name for p in mine.iterdir()] == ["notes.txt"]
    with pytest.raises(FarmUnavailable):
        tune(
            CONFIG,
            tmp_path / "runs" / "first",
            FarmOptions(connect=[f"tcp/127.0.0.1:{free_port()}"]),
        )
    assert sorted(path.name for path in tmp_path.iterdir()) == ["mine"]  # runs/ too


def test_a_run_s_defaults_are_analytic_start_s() -> None:
    """One source: RunConfig's defaults are what `analytic start` runs without options."""
    from gainfarm.analytic.commands.start import start

    with start.make_context("start", []) as context:
        given = context.params
    assert RunConfig().keep == "front" == given["keep"]
    config = RunConfig()
    for field in ("pop", "seed", "algorithm", "objective_scaling", "replicate"):
        assert given[field] == getattr(config, field), field
    (trajectory,) = config.trajectories
    assert given["kinds"] == (trajectory.kind,) and given["duration"] == trajectory.duration
    assert given["trajectory_seed"] == trajectory.seed and given["size"] == trajectory.size
    assert given["center"] == ",".join(f"{value:g}" for value in trajectory.center)
    assert resolve(values.model_spec(given["plant"], given["joints"])) == config.plant
    assert given["robot"] == config.robot == "iiwa14"
    assert given["balance"] is True and given["generations"] is given["evaluations"] is None
