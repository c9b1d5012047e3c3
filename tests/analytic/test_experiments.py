"""Each of the paper's experiments at toy size, on a real local farm."""

import csv
from collections.abc import Iterator
from pathlib import Path

import pytest

from analytic import experiments
from analytic.config import RunConfig
from analytic.experiments import EvaluatorFactory, Experiment, non_dominated
from analytic.farm import FarmClient
from analytic.inprocess import InProcessEvaluator
from analytic.local import local_farm
from schemas import TrajectorySpec
from tests.analytic.toy import toy_scores
from tests.helpers import analytic

BASE = RunConfig(pop=4, trajectories=(TrajectorySpec(duration=3.0),), generations=2, keep="front")
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def endpoints() -> Iterator[list[str]]:
    with local_farm(workers=2) as endpoint:
        yield [endpoint]


def on_farm(endpoints: list[str]) -> EvaluatorFactory:
    return lambda study, directory: FarmClient(endpoints, study, directory)


def rows(path: Path) -> list[dict[str, str]]:
    with path.open() as stream:
        return list(csv.DictReader(stream))


def test_popsize(tmp_path: Path, endpoints: list[str]) -> None:
    messages: list[str] = []
    experiments.popsize(
        Experiment(tmp_path, on_farm(endpoints), messages.append), BASE, sizes=[4, 6], reps=2
    )
    results = rows(tmp_path / "results.csv")
    assert [(r["pop"], r["rep"]) for r in results] == [
        ("4", "0"),
        ("4", "1"),
        ("6", "0"),
        ("6", "1"),
    ]
    assert [r["evaluations"] for r in results] == ["8", "8", "12", "12"]
    assert all(0 < float(r["hypervolume"]) <= 1 for r in results)
    assert (tmp_path / "popsize.png").read_bytes().startswith(PNG)
    report = (tmp_path / "report.md").read_text()
    assert "| 4 |" in report and "| 6 |" in report and "The paper found" in report
    assert messages  # progress was shown
    # Resumable: a second pass finds every run finished and simulates nothing more.
    before = {path: path.stat().st_mtime_ns for path in tmp_path.glob("runs/*/checkpoint.pkl")}
    experiments.popsize(Experiment(tmp_path, on_farm(endpoints)), BASE, sizes=[4, 6], reps=2)
    after = {path: path.stat().st_mtime_ns for path in tmp_path.glob("runs/*/checkpoint.pkl")}
    assert before == after and len(before) == 4


def test_generic_vs_specific(tmp_path: Path, endpoints: list[str]) -> None:
    experiments.generic_vs_specific(Experiment(tmp_path, on_farm(endpoints)), BASE, reps=1)
    results = rows(tmp_path / "results.csv")
    assert [r["controller"] for r in results] == ["generic", "specific"]
    generic = tmp_path / "runs" / "generic-rep0" / "config.json"
    assert generic.read_text().count('"kind"') == 3  # tuned on all three trajectories
    assert len(list((tmp_path / "cross" / "generic-rep0" / "episodes").glob("*.mcap"))) >= 1
    assert (tmp_path / "generic-vs-specific.png").read_bytes().startswith(PNG)
    assert "specific controller's median hypervolume" in (tmp_path / "report.md").read_text()


def test_speed(tmp_path: Path, endpoints: list[str]) -> None:
    experiments.speed(Experiment(tmp_path, on_farm(endpoints)), BASE, durations=[3.0, 3.5], reps=1)
    results = rows(tmp_path / "results.csv")
    assert [(r["tuned_on_s"], r["evaluated_on_s"]) for r in results] == [
        ("3.0", "3.0"),
        ("3.0", "3.5"),
        ("3.5", "3.0"),
        ("3.5", "3.5"),
    ]
    assert all(float(r["median_error_of_most_accurate_m"]) > 0 for r in results)
    assert (tmp_path / "speed.png").read_bytes().startswith(PNG)
    assert "| 3 s |" in (tmp_path / "report.md").read_text()


def test_an_experiment_uses_one_reference_point_the_worst_tested(tmp_path: Path) -> None:
    experiment = Experiment(tmp_path, on_farm([]))
    experiment.tested = [(0.1, 10.0), (0.3, 1.0), (0.2, 50.0)]
    assert experiment.reference == (0.3, 50.0)
    assert experiment.hypervolume([(0.3, 50.0)]) == 0.0
    assert (
        0
        < experiment.hypervolume([(0.1, 10.0)])
        < experiment.hypervolume([(0.1, 10.0), (0.05, 40.0)])
    )


def test_non_dominated() -> None:
    assert non_dominated([(1, 5), (2, 2), (3, 3), (1, 5)]) == [(1, 5), (2, 2), (1, 5)]


def test_an_experiment_runs_on_any_evaluator_and_resumes_without_rerunning(
    tmp_path: Path,
) -> None:
    def in_process(study: str, directory: Path) -> InProcessEvaluator:
        return InProcessEvaluator(scorer=toy_scores)

    experiments.popsize(Experiment(tmp_path, in_process), BASE, sizes=[4, 6], reps=2)
    results = rows(tmp_path / "results.csv")
    assert [r["evaluations"] for r in results] == ["8", "8", "12", "12"]
    assert all(r["stopped"] == "2 generations" for r in results)
    before = (tmp_path / "results.csv").read_bytes()
    checkpoints = {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/*/checkpoint.pkl")}

    def no_evaluator(study: str, directory: Path) -> InProcessEvaluator:
        raise AssertionError(f"{study} ran again")

    experiments.popsize(Experiment(tmp_path, no_evaluator), BASE, sizes=[4, 6], reps=2)
    assert (tmp_path / "results.csv").read_bytes() == before
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/*/checkpoint.pkl")} == checkpoints


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["speed", "--durations", "1,3"], "--durations: the 1 s spiral is too fast"),
        (["generic-vs-specific", "--duration", "2"], "--duration: the 2 s "),
    ],
)
def test_an_experiment_the_iiwa_cannot_follow_is_refused_before_anything_is_written(
    tmp_path: Path, arguments: list[str], message: str
) -> None:
    run = analytic("experiment", *arguments, "--local", "--out", "out", cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr.startswith("analytic: error: ") and message in run.stderr
    assert len(run.stderr.splitlines()) == 1
    assert not (tmp_path / "out").exists()
