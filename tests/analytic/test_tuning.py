"""`tune`, the one-call face of the analytic layer, as the README shows it."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from gainfarm.analytic import InProcessEvaluator, RunConfig, read_run, tune
from gainfarm.schemas import TrajectorySpec
from tests.analytic.toy import toy_scores

README = Path(__file__).parents[2] / "README.md"
CONFIG = RunConfig(
    pop=6, seed=1, trajectories=(TrajectorySpec(kind="fourier", duration=0.5),), generations=2
)


def test_the_readme_example_runs(tmp_path: Path) -> None:
    [example] = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)
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
