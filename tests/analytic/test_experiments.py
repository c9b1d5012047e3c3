"""Each of the paper's experiments at toy size, on a real local farm."""

import csv
import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.experiments import base as experiments
from gainfarm.analytic.experiments.base import (
    ALL_KINDS,
    EvaluatorFactory,
    Experiment,
    Normalisation,
    non_dominated,
)
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import read_front
from gainfarm.schemas import EpisodeSpec, Scores, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import NO_EPISODE, balancing_weights, score
from gainfarm.schemas.trajectory import TrajectoryKind
from tests.analytic.toy import toy_scores
from tests.helpers import analytic

BASE = RunConfig(pop=4, trajectories=(TrajectorySpec(duration=3.0),), generations=2, keep="front")
PNG = b"\x89PNG\r\n\x1a\n"
STATS_COLUMNS = "study,comparison,metric,median_a,median_b,p_value,a12,ci_low,ci_high,n_a,n_b"


@pytest.fixture(scope="module")
def endpoints() -> Iterator[list[str]]:
    with local_farm(workers=2) as endpoint:
        yield [endpoint]


def on_farm(endpoints: list[str]) -> EvaluatorFactory:
    return lambda study, directory: FarmClient(endpoints, study, directory)


def rows(path: Path) -> list[dict[str, str]]:
    with path.open() as stream:
        return list(csv.DictReader(stream))


def in_process(study: str, directory: Path) -> InProcessEvaluator:
    return InProcessEvaluator(scorer=toy_scores)


def stats_rows(out: Path) -> list[dict[str, str]]:
    assert (out / "stats.csv").read_text().splitlines()[0] == STATS_COLUMNS
    return rows(out / "stats.csv")


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
    assert all(0 <= float(r["hypervolume"]) <= 1 for r in results)
    assert (tmp_path / "popsize.png").read_bytes().startswith(PNG)
    report = (tmp_path / "report.md").read_text()
    assert "| 4 |" in report and "| 6 |" in report
    # 2 against 2 repetitions: no test can reach 0.05, and the report says so.
    assert "cannot decide where the hypervolume levels off" in report
    assert [r["comparison"] for r in stats_rows(tmp_path)] == ["pop 6 vs pop 4"] * 2
    assert "all runs" in json.loads((tmp_path / "normalisation.json").read_text())
    assert messages  # progress was shown
    # Resumable: a second pass finds every run finished and simulates nothing more.
    before = {path: path.stat().st_mtime_ns for path in tmp_path.glob("runs/*/checkpoint.pkl")}
    experiments.popsize(Experiment(tmp_path, on_farm(endpoints)), BASE, sizes=[4, 6], reps=2)
    after = {path: path.stat().st_mtime_ns for path in tmp_path.glob("runs/*/checkpoint.pkl")}
    assert before == after and len(before) == 4


def test_generic_vs_specific(tmp_path: Path, endpoints: list[str]) -> None:
    experiments.generic_vs_specific(
        Experiment(tmp_path, on_farm(endpoints)), BASE, reps=1, kinds=[TrajectoryKind.pyramid]
    )
    results = rows(tmp_path / "results.csv")
    assert [(r["test_trajectory"], r["controller"]) for r in results] == [
        ("pyramid", "generic"),
        ("pyramid", "specific"),
    ]
    generic = (tmp_path / "runs" / "generic-no-pyramid-rep0" / "config.json").read_text()
    assert generic.count('"kind"') == 2 and "pyramid" not in generic  # held out
    # Balanced by the default gains' own episodes on the generic set, read back from their logs.
    defaults = []
    for kind in ("spiral", "random"):
        [log] = (tmp_path / "cross" / f"default-gains-on-{kind}" / "episodes").glob("*.mcap")
        found = score(read_episode(log))
        defaults.append((found.f_acc, found.f_t))
    weights = RunConfig.model_validate_json(generic).objective_weights
    assert weights == balancing_weights(defaults)
    cross = tmp_path / "cross" / "generic-no-pyramid-rep0-on-pyramid" / "episodes"
    assert len(list(cross.glob("*.mcap"))) >= 1
    assert (tmp_path / "generic-vs-specific.png").read_bytes().startswith(PNG)
    report = (tmp_path / "report.md").read_text()
    assert "on the pyramid (held out of the generic set): cannot decide" in report
    assert "generic points" in report
    assert {r["metric"] for r in stats_rows(tmp_path)} == {
        "hypervolume",
        "best_f_acc",
        "dominated_share",
    }
    assert "By dominance, paired by repetition: cannot decide" in report  # 1 pair


def test_generic_vs_specific_holds_each_trajectory_out_in_turn(tmp_path: Path) -> None:
    experiments.generic_vs_specific(Experiment(tmp_path, in_process), BASE, reps=1)
    for kind in ALL_KINDS:
        generic = json.loads(
            (tmp_path / "runs" / f"generic-no-{kind.value}-rep0" / "config.json").read_text()
        )
        kinds = [trajectory["kind"] for trajectory in generic["trajectories"]]
        assert kind.value not in kinds and len(kinds) == 2
        specific = json.loads(
            (tmp_path / "runs" / f"specific-{kind.value}-rep0" / "config.json").read_text()
        )
        assert [trajectory["kind"] for trajectory in specific["trajectories"]] == [kind.value]
    results = rows(tmp_path / "results.csv")
    assert {r["test_trajectory"] for r in results} == {kind.value for kind in ALL_KINDS}
    assert all(0 <= int(r["dominated_by_other"]) <= int(r["points"]) for r in results)
    assert len(stats_rows(tmp_path)) == 9
    assert {r["metric"] for r in stats_rows(tmp_path)} == {
        "hypervolume",
        "best_f_acc",
        "dominated_share",
    }
    assert set(json.loads((tmp_path / "normalisation.json").read_text())) == {
        "on spiral",
        "on random",
        "on pyramid",
    }


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
    assert {r["metric"] for r in stats_rows(tmp_path)} == {"error_m", "hypervolume"}


def test_speed_in_process_writes_its_statistics(tmp_path: Path) -> None:
    experiments.speed(Experiment(tmp_path, in_process), BASE, durations=[3.0, 3.5, 4.0], reps=2)
    comparisons = {r["comparison"] for r in stats_rows(tmp_path)}
    assert "3.5 s vs 3 s, own spiral" in comparisons and "4 s vs 3.5 s, own spiral" in comparisons
    assert "tuned on 3 s vs tuned on 4 s, on 4 s" in comparisons
    assert (
        "cannot decide whether or where accuracy levels off" in (tmp_path / "report.md").read_text()
    )


def test_an_experiment_normalises_between_its_pooled_front_penalties_aside(tmp_path: Path) -> None:
    experiment = Experiment(tmp_path, on_farm([]))
    experiment.penalised.add((0.4, 1e5))  # a diverged episode met in a cross-evaluation
    fronts = [[(0.1, 10.0), (0.3, 1.0)], [(0.2, 50.0), NO_EPISODE, (0.4, 1e5)]]
    normalisation = experiment.normalisation(fronts)
    assert (normalisation.ideal, normalisation.nadir) == ((0.1, 1.0), (0.3, 10.0))
    assert normalisation.hypervolume([(0.2, 50.0)]) == 0.0  # beyond the reference point
    assert (
        0
        < normalisation.hypervolume([(0.3, 10.0)])
        < normalisation.hypervolume([(0.1, 10.0)])
        < normalisation.hypervolume([(0.1, 10.0), (0.3, 1.0)])
        <= 1
    )


def soft_diverges(spec: EpisodeSpec) -> Scores:
    """The toy's scores, flagged diverged for a first joint softer than the default's."""
    scores = toy_scores(spec)
    return scores.model_copy(update={"diverged": spec.gains.kp[0] < DEFAULT_GAINS.kp[0]})


def test_diverged_front_members_are_flagged_and_never_bound_the_normalisation(
    tmp_path: Path,
) -> None:
    experiment = Experiment(tmp_path, lambda _s, _d: InProcessEvaluator(scorer=soft_diverges))
    record = experiment.tune("run", BASE.model_copy(update={"pop": 8, "generations": 3}))
    front = read_front(record.directory / "front.csv")
    assert [m.diverged for m in front] == [m.kp[0] < DEFAULT_GAINS.kp[0] for m in front]
    flagged = {m.objectives for m in front if m.diverged}
    assert flagged and flagged != {m.objectives for m in front}  # both kinds on this front
    assert experiment.penalised == flagged
    normalisation = experiment.normalisation([[m.objectives for m in front]])
    measured = [m.objectives for m in front if not m.diverged]
    assert normalisation == Normalisation.of([measured])


def test_a_measure_levels_off_after_its_last_significant_gain_unless_that_is_the_last_step() -> (
    None
):
    assert experiments.level_from([20, 30], [10, 20, 30, 50, 80]) == 30
    assert experiments.level_from([], [10, 20, 30]) == 10
    assert experiments.level_from([20, 80], [10, 20, 30, 50, 80]) is None  # still rising


def test_non_dominated() -> None:
    assert non_dominated([(1, 5), (2, 2), (3, 3), (1, 5)]) == [(1, 5), (2, 2), (1, 5)]


def test_an_experiment_runs_on_any_evaluator_and_resumes_without_rerunning(
    tmp_path: Path,
) -> None:
    experiments.popsize(Experiment(tmp_path, in_process), BASE, sizes=[4, 6], reps=2)
    results = rows(tmp_path / "results.csv")
    assert [r["evaluations"] for r in results] == ["8", "8", "12", "12"]
    assert all(r["stopped"] == "2 generations" for r in results)
    assert [r["metric"] for r in stats_rows(tmp_path)] == ["hypervolume", "evaluations"]
    before = (tmp_path / "results.csv").read_bytes()
    checkpoints = {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/*/checkpoint.pkl")}

    def no_evaluator(study: str, directory: Path) -> InProcessEvaluator:
        raise AssertionError(f"{study} ran again")

    experiments.popsize(Experiment(tmp_path, no_evaluator), BASE, sizes=[4, 6], reps=2)
    assert (tmp_path / "results.csv").read_bytes() == before
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("runs/*/checkpoint.pkl")} == checkpoints


def without_wall_times(path: Path) -> list[dict[str, str]]:
    return [{k: v for k, v in row.items() if k != "wall_seconds"} for row in rows(path)]


@pytest.mark.parametrize(
    ("study", "arguments"),
    [
        (experiments.popsize, {"sizes": [4, 6], "reps": 2}),
        (experiments.generic_vs_specific, {"reps": 2}),
        (experiments.speed, {"durations": [3.0, 3.5], "reps": 2}),
    ],
)
def test_an_experiment_writes_the_same_results_one_run_at_a_time_as_all_at_once(
    tmp_path: Path, study: Callable[..., None], arguments: dict[str, object]
) -> None:
    for parallel in (1, None):
        study(
            Experiment(tmp_path / str(parallel), in_process, parallel=parallel), BASE, **arguments
        )
    one, all_at_once = tmp_path / "1", tmp_path / "None"
    for name in ("stats.csv", "normalisation.json"):
        assert (one / name).read_bytes() == (all_at_once / name).read_bytes()
    # Wall times differ from one run to the next; every other column is the same.
    assert without_wall_times(one / "results.csv") == without_wall_times(
        all_at_once / "results.csv"
    )


def test_two_processes_share_an_experiment_each_run_run_once(tmp_path: Path) -> None:
    """Two experiments on one --out (as two processes, each run's lock being a flock of its
    own open file), one run at a time each: each takes the runs the other is not running, waits
    for the rest, and both end with the same results; every run was run by one of them. (Each
    moves the fronts it has to the other durations itself: cross-evaluations are not kept.)"""
    ran: dict[str, list[str]] = {"a": [], "b": []}

    def slow(who: str) -> EvaluatorFactory:
        def evaluator(study: str, directory: Path) -> InProcessEvaluator:
            if directory.parent.name == "runs":
                ran.setdefault(who, []).append(directory.name)
                time.sleep(0.3)  # long enough for the other to find this run taken
            return InProcessEvaluator(scorer=toy_scores)

        return evaluator

    def share(who: str) -> None:
        experiments.speed(
            Experiment(tmp_path, slow(who), parallel=1), BASE, [3.0, 3.5, 4.0], reps=2
        )

    other = threading.Thread(target=share, args=("b",))
    other.start()
    share("a")
    other.join(120)
    assert not other.is_alive()
    runs = sorted(p.name for p in (tmp_path / "runs").iterdir())
    assert sorted(ran["a"] + ran["b"]) == runs and len(runs) == 6  # each run once
    assert ran["a"] and ran["b"]  # and both took some
    results = (tmp_path / "results.csv").read_bytes()
    experiments.speed(Experiment(tmp_path, slow("none")), BASE, [3.0, 3.5, 4.0], reps=2)
    assert "none" not in ran
    assert (tmp_path / "results.csv").read_bytes() == results


class Interrupted(Exception):
    pass


def test_a_run_that_fails_fails_the_experiment_which_goes_on_when_run_again(
    tmp_path: Path,
) -> None:
    experiments.speed(Experiment(tmp_path / "whole", in_process), BASE, [3.0, 3.5], reps=2)
    scored: list[str] = []

    def failing(study: str, directory: Path) -> InProcessEvaluator:
        def score(spec: EpisodeSpec) -> Scores:
            scored.append(study)
            if study.endswith("spiral3.5s-rep0") and scored.count(study) == 3:
                raise Interrupted  # as Ctrl-C or a lost farm would, mid-run
            return toy_scores(spec)

        return InProcessEvaluator(scorer=score)

    out = tmp_path / "interrupted"
    with pytest.raises(Interrupted):
        experiments.speed(Experiment(out, failing), BASE, [3.0, 3.5], reps=2)
    assert not (out / "results.csv").exists()
    unfinished = [d.name for d in (out / "runs").iterdir() if not (d / "report.md").exists()]
    assert "spiral3.5s-rep0" in unfinished
    experiments.speed(Experiment(out, in_process), BASE, [3.0, 3.5], reps=2)
    for name in ("results.csv", "stats.csv", "normalisation.json"):
        assert (out / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()


def test_ctrl_c_stops_an_experiment_of_runs_at_once_and_the_same_command_goes_on(
    tmp_path: Path,
) -> None:
    command = [
        *("experiment", "popsize", "--sizes", "4,6", "--reps", "2", "--pop", "4"),
        *("--generations", "3", "--duration", "3", "--local", "--workers", "2"),
        *("--parallel-runs", "3", "--out", "study"),
    ]
    running = subprocess.Popen(
        [sys.executable, "-m", "gainfarm.analytic", *command],
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        give_up = time.monotonic() + 120
        while not any((tmp_path / "study" / "runs").glob("*/history.csv")):
            assert time.monotonic() < give_up and running.poll() is None
            time.sleep(0.05)
    finally:
        running.send_signal(signal.SIGINT)
        try:
            _, err = running.communicate(timeout=60)
        finally:
            running.kill()  # never left running, whatever happened above
    assert running.returncode == 130, err
    assert "stopped; run the same command again to go on" in err
    assert not (tmp_path / "study" / "results.csv").exists()
    done = analytic(*command, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    results = rows(tmp_path / "study" / "results.csv")
    assert [r["evaluations"] for r in results] == ["12", "12", "18", "18"]
    assert all(r["stopped"] == "3 generations" for r in results)


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
