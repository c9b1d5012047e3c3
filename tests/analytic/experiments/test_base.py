"""What every experiment shares: the runner (runs at once, resumed, shared between processes,
stopped), the normalised space, the "levels off" finding, the report's frame, the registry and
the command that runs an experiment by name."""

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from gainfarm import plugins
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import findings, generic_vs_specific, popsize, registry, speed
from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.normalisation import (
    Normalisation,
    dominated_count,
    is_penalty,
    non_dominated,
)
from gainfarm.analytic.experiments.report import experiment_setup
from gainfarm.analytic.experiments.runner import EvaluatorFactory, Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import read_front
from gainfarm.schemas import EpisodeSpec, Scores, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.objectives import NO_EPISODE
from tests.analytic.experiments.common import BASE, in_process, on_farm, refusal, rows
from tests.analytic.toy import toy_scores
from tests.helpers import analytic


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


def test_the_normalisation_spans_the_pooled_front_and_ignores_penalty_points() -> None:
    runs = [[(0.01, 100.0), (0.05, 1.0)], [(0.02, 10.0), (0.08, 50.0)]]  # the last dominated
    normalisation = Normalisation.of(runs)
    assert normalisation.ideal == (0.01, 1.0) and normalisation.nadir == (0.05, 100.0)
    diverged = (0.5, 1e6)
    with_penalties = Normalisation.of([*runs, [NO_EPISODE, diverged], [(1.0, 0.5)]], {diverged})
    assert with_penalties == normalisation
    assert is_penalty(NO_EPISODE) and is_penalty(diverged, {diverged})
    assert not is_penalty((0.5, 1e6))
    # The whole range is used: the pooled front scores high, its worst corner little.
    assert normalisation.hypervolume([(0.05, 100.0)]) == pytest.approx(0.01 / 1.21)
    assert normalisation.hypervolume([p for points in runs for p in points]) > 0.4
    assert normalisation.hypervolume([NO_EPISODE]) == 0.0
    assert normalisation.normalise([(0.03, 10.0)])[0].tolist() == pytest.approx([0.5, 0.5])


def test_dominance_counts() -> None:
    specific = [(0.01, 1.0), (0.02, 0.5)]
    generic = [(0.02, 2.0), (0.005, 10.0), (0.02, 0.5)]
    assert dominated_count(generic, specific) == 1  # (0.02, 0.5) ties, is not dominated
    assert dominated_count(specific, generic) == 0


def test_a_measure_levels_off_after_its_last_significant_gain_unless_that_is_the_last_step() -> (
    None
):
    assert findings.level_from([20, 30], [10, 20, 30, 50, 80]) == 30
    assert findings.level_from([], [10, 20, 30]) == 10
    assert findings.level_from([20, 80], [10, 20, 30, 50, 80]) is None  # still rising


def test_non_dominated() -> None:
    assert non_dominated([(1, 5), (2, 2), (3, 3), (1, 5)]) == [(1, 5), (2, 2), (1, 5)]


def without_wall_times(path: Path) -> list[dict[str, str]]:
    return [{k: v for k, v in row.items() if k != "wall_seconds"} for row in rows(path)]


@pytest.mark.parametrize(
    ("run", "arguments"),
    [
        (popsize.run, {"sizes": [4, 6], "reps": 2}),
        (generic_vs_specific.run, {"reps": 2}),
        (speed.run, {"durations": [3.0, 3.5], "reps": 2}),
    ],
)
@pytest.mark.slow
def test_an_experiment_writes_the_same_results_one_run_at_a_time_as_all_at_once(
    tmp_path: Path, run: Callable[..., None], arguments: dict[str, object]
) -> None:
    for parallel in (1, None):
        run(Experiment(tmp_path / str(parallel), in_process, parallel=parallel), BASE, **arguments)
    one, all_at_once = tmp_path / "1", tmp_path / "None"
    for name in ("stats.csv", "normalisation.json"):
        assert (one / name).read_bytes() == (all_at_once / name).read_bytes()
    # Wall times differ from one run to the next; every other column is the same.
    assert without_wall_times(one / "results.csv") == without_wall_times(
        all_at_once / "results.csv"
    )


@pytest.mark.slow
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
        speed.run(
            Experiment(tmp_path, slow(who), parallel=1), BASE, reps=2, durations=[3.0, 3.5, 4.0]
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
    speed.run(Experiment(tmp_path, slow("none")), BASE, reps=2, durations=[3.0, 3.5, 4.0])
    assert "none" not in ran
    assert (tmp_path / "results.csv").read_bytes() == results


class Interrupted(Exception):
    pass


@pytest.mark.slow
def test_a_run_that_fails_fails_the_experiment_which_goes_on_when_run_again(
    tmp_path: Path,
) -> None:
    speed.run(Experiment(tmp_path / "whole", in_process), BASE, reps=2, durations=[3.0, 3.5])
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
        speed.run(Experiment(out, failing), BASE, reps=2, durations=[3.0, 3.5])
    assert not (out / "results.csv").exists()
    unfinished = [d.name for d in (out / "runs").iterdir() if not (d / "report.md").exists()]
    assert "spiral3.5s-rep0" in unfinished
    speed.run(Experiment(out, in_process), BASE, reps=2, durations=[3.0, 3.5])
    for name in ("results.csv", "stats.csv", "normalisation.json"):
        assert (out / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()


@pytest.mark.slow
def test_ctrl_c_stops_an_experiment_of_runs_at_once_and_the_same_command_goes_on(
    tmp_path: Path,
) -> None:
    command = [
        *("experiment", "popsize", "--sizes", "4,6", "--reps", "2", "--pop", "4"),
        *("--generations", "2", "--duration", "3", "--local", "--workers", "2"),
        *("--parallel-runs", "3", "--out", "out"),
    ]
    running = subprocess.Popen(
        [sys.executable, "-m", "gainfarm.analytic", *command],
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        give_up = time.monotonic() + 120
        while not any((tmp_path / "out" / "runs").glob("*/history.csv")):
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
    assert not (tmp_path / "out" / "results.csv").exists()
    done = analytic(*command, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    results = rows(tmp_path / "out" / "results.csv")
    assert [r["evaluations"] for r in results] == ["8", "8", "12", "12"]
    assert all(r["stopped"] == "2 generations" for r in results)


HIGH = [1.0, 1.1, 1.2, 1.3, 1.4]
LOW = [0.0, 0.1, 0.2, 0.3, 0.4]


def test_one_levels_off_finding_for_a_measure_that_rises_and_one_that_falls() -> None:
    gain, none = stats.compare(HIGH, LOW), stats.compare(HIGH, HIGH)
    rising = findings.levels_off({(10, 20): gain, (20, 30): gain}, 5, "the hypervolume", "size")
    assert rising.rising and rising.level is None
    assert rising.text.startswith("The hypervolume still gains significantly at the last size")
    levels = findings.levels_off({(10, 20): gain, (20, 30): none}, 5, "the hypervolume", "size")
    assert (levels.level, levels.rising) == (20, False)
    assert levels.text.startswith("The hypervolume levels off from size 20 (no significant")
    flat = findings.levels_off({(10, 20): none}, 5, "the hypervolume", "size")
    assert flat.level == 10 and "no significant gain between consecutive sizes" in flat.text
    # Lower is better: an error that falls gains; shown with its unit.
    falls = stats.compare(LOW, HIGH)
    error = findings.levels_off(
        {(3.0, 4.0): falls, (4.0, 5.0): none}, 5, "accuracy", "duration", "{:g} s".format, False
    )
    assert error.text.startswith("Accuracy levels off from duration 4 s")
    assert findings.levels_off({}, 5, "accuracy", "duration").text == (
        "One duration only: nothing to compare."
    )
    undecided = findings.levels_off({(3.0, 4.0): stats.compare([1, 2], [0, 1])}, 2, "accuracy", "s")
    assert undecided.level is None and "cannot decide whether or where accuracy" in undecided.text


def test_the_steps_compare_each_setting_with_the_next_smaller() -> None:
    steps = findings.step_comparisons({30: HIGH, 10: LOW, 20: LOW})
    assert list(steps) == [(10, 20), (20, 30)]
    assert steps[(20, 30)] == stats.compare(HIGH, LOW)


def test_an_experiment_states_the_populations_and_durations_its_runs_used() -> None:
    config = RunConfig(trajectories=(TrajectorySpec(duration=4.0),))
    normalisation = {"all": ((0.0, 0.0), (1.0, 1.0))}
    assert (
        "runs of population 30, trajectory duration 4 s,"
        in experiment_setup(config, 3, normalisation)[0]
    )
    sizes = experiment_setup(config, 3, normalisation, populations=[10, 20])[0]
    assert "runs of populations 10, 20, trajectory duration 4 s," in sizes
    speeds = experiment_setup(config, 3, normalisation, durations=[3.0, 4.0, 5.0])[0]
    assert "runs of population 30, trajectory durations 3, 4, 5 s," in speeds


# --- the registry and the command --------------------------------------------------------------


def test_the_registry_finds_every_built_in_experiment_by_its_command_line_name() -> None:
    found = registry.names()
    assert found[:7] == (
        "popsize",
        "generic-vs-specific",
        "speed",
        "algorithms",
        "dataset-value",
        "sensitivity",
        "feedforward",
    )
    for name in found:
        spec = registry.load(name)
        assert spec.name == name and callable(spec.run) and spec.summary
    assert registry.load("popsize") is popsize.EXPERIMENT
    with pytest.raises(plugins.PluginError) as unknown:
        registry.load("nope")
    assert str(unknown.value) == (
        f"gainfarm.experiments: no plug-in named 'nope' here (there are {', '.join(found)}); "
        "install the distribution that provides it"
    )


def test_an_experiment_registered_follows_the_rules_of_every_plug_in_group() -> None:
    """The name rule, the built-in names reserved, and a declaration that is no ExperimentSpec
    of its own name refused in one line."""
    with pytest.raises(ValueError, match="plug-in name 'Toy': a lower-case letter"):
        plugins.register(registry.GROUP, "Toy", popsize.EXPERIMENT)
    with pytest.raises(ValueError, match="'speed' is a built-in name; choose another"):
        plugins.register(registry.GROUP, "speed", popsize.EXPERIMENT)
    try:
        plugins.register(registry.GROUP, "not-a-spec", popsize.run)
        plugins.register(registry.GROUP, "renamed", popsize.EXPERIMENT)
        assert {"not-a-spec", "renamed"} <= set(registry.names())
        for name in ("not-a-spec", "renamed"):
            with pytest.raises(plugins.PluginError) as refused:
                registry.load(name)
            assert str(refused.value) == (
                f"gainfarm.experiments: plug-in {name!r} is no ExperimentSpec named {name!r}"
            )
    finally:
        plugins.unregister(registry.GROUP, "not-a-spec")
        plugins.unregister(registry.GROUP, "renamed")


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["speed", "--sizes", "4,6"], "--sizes: an option of popsize, not of speed"),
        (["popsize", "--ticks", "20"], "--ticks: an option of dataset-value, not of popsize"),
        (["speed", "--duration", "4"], "--duration: an option of algorithms, dataset-value, "),
        (["nope"], "NAME: gainfarm.experiments: no plug-in named 'nope' here (there are popsize, "),
        (["popsize", "--sizes", "4,x"], "--sizes: expected comma-separated numbers, got '4,x'"),
        (["popsize", "--sizes", "4,2"], "--sizes: 2 is not a population size (4-1000)"),
        # A trajectory the iiwa cannot follow: refused before any job is sent.
        (["speed", "--durations", "1,3"], "--durations: the 1 s spiral is too fast"),
        (["generic-vs-specific", "--duration", "2"], "--duration: the 2 s "),
    ],
)
@pytest.mark.slow
def test_bad_input_to_an_experiment_is_one_line_naming_the_option_before_anything_is_written(
    tmp_path: Path, arguments: list[str], message: str
) -> None:
    assert refusal(tmp_path, *arguments).startswith(message)


@pytest.mark.parametrize(
    ("out", "says"),
    [
        ("notes", "--out: 'notes' is a file, not a directory"),
        ("notes/experiment", "--out: cannot write 'notes/experiment': 'notes' is a file"),
    ],
)
def test_an_experiment_out_that_is_or_is_under_a_file_is_one_line_naming_it(
    tmp_path: Path, out: str, says: str
) -> None:
    (tmp_path / "notes").write_text("mine")
    run = analytic("experiment", "popsize", "--local", "--out", out, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr == f"analytic: error: {says}\n"
    assert (tmp_path / "notes").read_text() == "mine"


TOY_EXPERIMENT = '''
"""A plug-in experiment: one module, declared in its distribution's entry points."""

from gainfarm.analytic.experiments.registry import ExperimentSpec, Option, numbers


def run(experiment, base, reps, gains=(1.0,)):
    text = f"toy: {reps} repetitions, population {base.pop}, gains {list(gains)}\\n"
    (experiment.out / "report.md").write_text(text)


EXPERIMENT = ExperimentSpec(
    name="toy",
    summary="a toy experiment from another distribution",
    run=run,
    options=(Option("--gains", "gains", "comma-separated", "1", numbers(float)),),
    duration=None,
    trajectories=lambda base, options: [],
)
'''


@pytest.mark.slow
def test_an_installed_distribution_adds_an_experiment_with_no_edit_to_the_command(
    tmp_path: Path,
) -> None:
    """A module and an entry point in `gainfarm.experiments` (a dist-info on the path, as pip
    installs one): listed, run with its own option, and its option refused for the others."""
    plugin = tmp_path / "plugin"
    (plugin / "toy_experiment-0.1.dist-info").mkdir(parents=True)
    (plugin / "toy_experiment-0.1.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: toy-experiment\nVersion: 0.1\n"
    )
    (plugin / "toy_experiment-0.1.dist-info" / "entry_points.txt").write_text(
        f"[{registry.GROUP}]\ntoy = toy_experiment:EXPERIMENT\n"
    )
    (plugin / "toy_experiment.py").write_text(TOY_EXPERIMENT)

    def command(*arguments: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "gainfarm.analytic", "experiment", *arguments],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=300,
            env={**os.environ, "PYTHONPATH": str(plugin), "COLUMNS": "200"},
        )

    listed = command("--help")
    assert listed.returncode == 0 and "a toy experiment from another distribution" in listed.stdout
    # No farm is reached: the toy simulates nothing.
    done = command(
        "toy", "--gains", "2,3", "--reps", "2", "--connect", "tcp/127.0.0.1:9", "--out", "out"
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out" / "report.md").read_text() == (
        "toy: 2 repetitions, population 30, gains [2.0, 3.0]\n"
    )
    refused = command("popsize", "--gains", "2", "--out", "elsewhere")
    assert refused.stderr == "analytic: error: --gains: an option of toy, not of popsize\n"
