"""The population-size experiment at toy size: on a real local farm, and in this process."""

import json
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import popsize
from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.measures import error_at, recommended
from gainfarm.analytic.experiments.normalisation import front_points
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning.records import read_run
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
    assert [r["comparison"] for r in stats_rows(tmp_path)] == ["pop 6 vs pop 4"] * 5
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
    assert [r["metric"] for r in stats_rows(tmp_path)] == [
        "hypervolume",
        "error_at_level_mm",
        "recommended_error_mm",
        "recommended_f_t",
        "evaluations",
    ]
    assert {r["experiment"] for r in stats_rows(tmp_path)} == {"popsize"}
    # Beside each hypervolume, what a run gives in mm and (N·m)²: its front's error at the
    # smoothness every front reaches, and its recommended controller's error and f_t.
    level = max(min(p[1] for p in front_points(read_run(d))) for d in (tmp_path / "runs").iterdir())
    for r in results:
        run = read_run(tmp_path / "runs" / f"pop{r['pop']}-rep{r['rep']}")
        assert float(r["f_t_level"]) == level
        assert float(r["error_at_level_mm"]) == error_at(front_points(run), level) * 1000
        pick = recommended(run)
        assert r["recommended"] == pick.name and pick.name in ("recommended", "closest")
        assert float(r["recommended_error_mm"]) == pick.member.f_acc * 1000
        assert float(r["recommended_f_t"]) == pick.member.f_t
    report = (tmp_path / "report.md").read_text()
    assert "  - recommended controller's error, " in report and " mm [" in report
    assert "  - recommended controller's f_t, " in report and " (N·m)² [" in report
    before = (tmp_path / "results.csv").read_bytes()
    checkpoints = {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/*/checkpoint.pkl")}

    def no_evaluator(study: str, directory: Path) -> InProcessEvaluator:
        raise AssertionError(f"{study} ran again")

    popsize.run(Experiment(tmp_path, no_evaluator), BASE, reps=2, sizes=[4, 6])
    assert (tmp_path / "results.csv").read_bytes() == before
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/*/checkpoint.pkl")} == checkpoints


def test_the_findings_place_the_level_against_the_papers_population_near_30() -> None:
    clear = stats.compare([1.0, 1.1, 1.2, 1.3, 1.4], [0.0, 0.1, 0.2, 0.3, 0.4])
    none = stats.compare([1.0, 1.1, 1.2, 1.3, 1.4], [1.0, 1.1, 1.2, 1.3, 1.4])
    levels = popsize.findings({(10, 30): clear, (30, 50): none}, reps=5)
    assert levels.startswith("The hypervolume levels off from population size 30 ")
    assert "this holds here." in levels
    rising = popsize.findings({(10, 30): none, (30, 50): clear}, reps=5)
    assert "does not level off within these population sizes" in rising
    assert "weigh the gains above" in rising
    assert "- pop 50 against pop 30: pop 50 is better than pop 30" in rising


def test_the_consecutive_steps_are_one_family_holm_adjusted() -> None:
    """Two steps each significant alone (p = 0.045) are not as the family of two they are."""
    high = [10.0, 11.0, 12.0, 13.0, 14.0, 15.0, 16.0, 17.0]
    alone = stats.compare(high, [v - 3 for v in high])
    assert stats.significant(alone)
    steps = {(10, 20): alone, (20, 30): alone}
    error = stats.compare([v / 10 for v in high], [v / 10 + 0.3 for v in high])
    said = popsize.findings(steps, reps=8, practical={"error_at_level_mm": {(10, 20): error}})
    assert "shows no significant gain between consecutive population sizes" in said
    assert (
        "- pop 20 against pop 10: cannot decide between pop 20 and pop 10: no significant " in said
    )
    assert f"p = {2 * alone.p_value:.3g}" in said  # Holm's, not the test's own
    assert "(hypervolume +3 [" in said  # its size beside, significant or not
    assert "  - error at the smoothness level, -0.3 mm [" in said


def test_a_population_size_no_run_may_have_is_refused_by_the_option() -> None:
    assert popsize.population_sizes("10,4,1000") == [10, 4, 1000]
    for text, says in (("4,3", "3 is not a population size (4-1000)"), ("4,x", "numbers")):
        try:
            popsize.population_sizes(text)
        except ValueError as error:
            assert says in str(error)
        else:
            raise AssertionError(f"{text!r} was taken")
