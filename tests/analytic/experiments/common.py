"""What the experiments' tests share: a toy-sized base configuration, the toy evaluator in this
process, and readers of the files an experiment writes."""

import csv
from pathlib import Path

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments.runner import EvaluatorFactory
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.schemas import TrajectorySpec
from tests.analytic.toy import toy_scores
from tests.helpers import analytic

BASE = RunConfig(pop=4, trajectories=(TrajectorySpec(duration=3.0),), generations=2, keep="front")
PNG = b"\x89PNG\r\n\x1a\n"
STATS_COLUMNS = "experiment,comparison,metric,median_a,median_b,p_value,a12,ci_low,ci_high,n_a,n_b"


def on_farm(endpoints: list[str]) -> EvaluatorFactory:
    return lambda study, directory: FarmClient(endpoints, study, directory)


def in_process(study: str, directory: Path) -> InProcessEvaluator:
    return InProcessEvaluator(scorer=toy_scores)


def rows(path: Path) -> list[dict[str, str]]:
    with path.open() as stream:
        return list(csv.DictReader(stream))


def stats_rows(out: Path) -> list[dict[str, str]]:
    assert (out / "stats.csv").read_text().splitlines()[0] == STATS_COLUMNS
    return rows(out / "stats.csv")


def refusal(tmp_path: Path, *arguments: str) -> str:
    """What `analytic experiment ARGUMENTS --local --out out` says when it refuses them: one
    line, exit status 2, and nothing written."""
    run = analytic("experiment", *arguments, "--local", "--out", "out", cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert len(run.stderr.splitlines()) == 1, run.stderr
    assert not (tmp_path / "out").exists()
    return run.stderr.removeprefix("analytic: error: ")
