"""The population-size experiment at toy size: on a real local farm, and in this process."""

import json
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import popsize
from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.base import Experiment
from tests.analytic.experiments.common import (
    BASE,
    PNG,
    in_process,
    on_farm,
    rows,
    stats_rows,
)


@pytest.mark.slow
def test_popsize(tmp_path: Path, endpoints: list[str]) -> None:
    messages: list[str] = []
    popsize.run(
        Experiment(tmp_path, on_farm(endpoints), messages.append), BASE, reps=2, sizes=[4, 6]
    )
    results = rows(tmp_path / "results.csv")
    assert [(r["pop"], r["rep"]) for r in results] == [
        ("4", "0"),
        ("4", "1"),
        ("6", "0"),
        ("6", "1"),
    ]
    assert [r["evaluations"] for r in results] == ["8", "8", "12", "12"]
    assert all(0 <= float(r["hypervolume"]) <= 1 for r in results)
    assert (tmp_path / "popsize.png").read_bytes().startswith(PNG)
    report = (tmp_path / "report.md").read_text()
    assert "| 4 |" in report and "| 6 |" in report
    # 2 against 2 repetitions: no test can reach 0.05, and the report says so.
    assert "cannot decide whether or where the hypervolume levels off" in report
    assert [r["comparison"] for r in stats_rows(tmp_path)] == ["pop 6 vs pop 4"] * 2
    assert "all runs" in json.loads((tmp_path / "normalisation.json").read_text())
    assert messages  # progress was shown
    # Resumable: a second pass finds every run finished and simulates nothing more.
    before = {path: path.stat().st_mtime_ns for path in tmp_path.glob("runs/*/checkpoint.pkl")}
    popsize.run(Experiment(tmp_path, on_farm(endpoints)), BASE, reps=2, sizes=[4, 6])
    after = {path: path.stat().st_mtime_ns for path in tmp_path.glob("runs/*/checkpoint.pkl")}
    assert before == after and len(before) == 4


@pytest.mark.slow
def test_an_experiment_runs_on_any_evaluator_and_resumes_without_rerunning(
    tmp_path: Path,
) -> None:
    popsize.run(Experiment(tmp_path, in_process), BASE, reps=2, sizes=[4, 6])
    results = rows(tmp_path / "results.csv")
    assert [r["evaluations"] for r in results] == ["8", "8", "12", "12"]
    assert all(r["stopped"] == "2 generations" for r in results)
    assert [r["metric"] for r in stats_rows(tmp_path)] == ["hypervolume", "evaluations"]
    assert {r["experiment"] for r in stats_rows(tmp_path)} == {"popsize"}
    before = (tmp_path / "results.csv").read_bytes()
    checkpoints = {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/*/checkpoint.pkl")}

    def no_evaluator(study: str, directory: Path) -> InProcessEvaluator:
        raise AssertionError(f"{study} ran again")

    popsize.run(Experiment(tmp_path, no_evaluator), BASE, reps=2, sizes=[4, 6])
    assert (tmp_path / "results.csv").read_bytes() == before
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/*/checkpoint.pkl")} == checkpoints


def test_the_verdict_places_the_level_against_the_papers_population_near_30() -> None:
    clear = stats.compare([1.0, 1.1, 1.2, 1.3, 1.4], [0.0, 0.1, 0.2, 0.3, 0.4])
    none = stats.compare([1.0, 1.1, 1.2, 1.3, 1.4], [1.0, 1.1, 1.2, 1.3, 1.4])
    levels = popsize.verdict({(10, 30): clear, (30, 50): none}, reps=5)
    assert levels.startswith("The hypervolume levels off from population size 30 ")
    assert "this holds here." in levels
    rising = popsize.verdict({(10, 30): none, (30, 50): clear}, reps=5)
    assert "does not level off within these population sizes" in rising
    assert "weigh the gains above" in rising
    assert "- pop 50 against pop 30: pop 50 is better than pop 30" in rising


def test_a_population_size_no_run_may_have_is_refused_by_the_option() -> None:
    assert popsize.population_sizes("10,4,1000") == [10, 4, 1000]
    for text, says in (("4,3", "3 is not a population size (4-1000)"), ("4,x", "numbers")):
        try:
            popsize.population_sizes(text)
        except ValueError as error:
            assert says in str(error)
        else:
            raise AssertionError(f"{text!r} was taken")
