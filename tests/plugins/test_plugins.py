"""Plug-ins (gainfarm.plugins): an optimiser, a trajectory kind and an objective from a real
distribution (tests/plugins/fixture), installed on the path with the metadata setuptools makes
of it, tuned with in this process and on a local farm; and a worker without them refuses the
job, naming the plug-in: the job runs on another worker, and the run stops with that reason,
instead of hanging or scoring nothing, only when no other worker is left to run it or this
process lacks the plug-in too."""

import importlib
import os
import re
import shutil
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from pydantic import ValidationError

from gainfarm import plugins
from gainfarm.analytic.cli import main as analytic_main
from gainfarm.analytic.compose import FarmOptions, tune
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import spawn_worker, stop_workers
from gainfarm.analytic.tuning.checkpoint import CheckpointRefused, decode, encode
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import Evolution
from gainfarm.analytic.tuning.records import RunIdentity, read_run
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.analytic.view.figures import pareto_figure
from gainfarm.broker.service import Broker
from gainfarm.cli import interrupts
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.objectives import score
from gainfarm.schemas.trajectory import KIND_PATTERN, TrajectorySpec
from gainfarm.schemas.wire import JobStatus
from gainfarm.testing.algorithms import AlgorithmChecks
from gainfarm.testing.experiments import ExperimentChecks
from gainfarm.testing.objectives import check_objective
from gainfarm.testing.trajectories import TrajectoryChecks
from gainfarm.worker.episode import run_episode
from gainfarm.worker.job import simulate
from tests.helpers import wait_for

ROOT = Path(__file__).parents[2]
FIXTURE = Path(__file__).with_name("fixture")
# A circle the arm follows in 1 s (0.9 s at least: worker.reference.shortest_duration).
CIRCLE = TrajectorySpec(kind="circle", duration=1.0, size=0.02, twist=0.0)
FOURIER = TrajectorySpec(kind="fourier", duration=0.2)  # a built-in episode, quick
# A run with all three (made once they are installed: a config names only what is here).
WITH_ALL_THREE = dict(
    pop=4,
    generations=2,
    seed=3,
    trajectories=(CIRCLE,),
    algorithm="hill_climb",
    objectives=("f_acc", "peak_torque"),
)


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The fixture distribution installed into a directory of its own: its package, and the
    metadata setuptools makes of its pyproject.toml (entry_points.txt among it), which is what
    importlib.metadata reads of an installed distribution. (setuptools' egg_info rather than
    `pip install --target`: this venv's setuptools builds no wheel without the `wheel` package,
    and pip's isolated build fetches one from the package index, 20 s.) On this process's path,
    and on its subprocesses' PYTHONPATH with `on_workers`."""
    root = tmp_path_factory.mktemp("plugins")
    source = shutil.copytree(FIXTURE, root / "source")  # a build writes beside its source
    target = root / "site"
    target.mkdir()
    setup = "from setuptools import setup; setup()"
    subprocess.run(
        [sys.executable, "-W", "ignore", "-c", setup, "-q", "egg_info", "--egg-base", str(target)],
        cwd=source,
        check=True,
        capture_output=True,
        timeout=120,
    )
    shutil.copytree(source / "gainfarm_fixture", target / "gainfarm_fixture")
    assert (target / "gainfarm_fixture_plugins.egg-info" / "entry_points.txt").is_file()
    sys.path.insert(0, str(target))
    importlib.invalidate_caches()
    try:
        yield target
    finally:
        sys.path.remove(str(target))
        sys.modules.pop("gainfarm_fixture", None)
        plugins._loaded.clear()  # uninstalled: later tests must not find them loaded


@pytest.fixture
def on_workers(installed: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The plug-ins on the path of the worker processes a local farm starts."""
    path = os.environ.get("PYTHONPATH")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(installed), *([path] if path else [])]))
    return installed


# --- the registry ---------------------------------------------------------------------------


def test_each_group_lists_its_built_ins_first_the_default_leading() -> None:
    assert plugins.builtin_names(plugins.ALGORITHMS)[0] == "nsga2"
    assert plugins.builtin_names(plugins.TRAJECTORIES) == ("spiral", "random", "pyramid", "fourier")
    assert plugins.builtin_names(plugins.OBJECTIVES) == ("f_acc", "f_t", "f_t_joint")
    for group in plugins.GROUPS:
        builtin = plugins.builtin_names(group)
        assert builtin[: len(plugins.ORDER[group])] == plugins.ORDER[group]
        assert plugins.names(group)[: len(builtin)] == builtin


def test_the_built_ins_are_gainfarms_own_entry_points_as_pyproject_declares_them() -> None:
    """They are read from the installation's metadata: one older than pyproject.toml (an
    editable install made before a built-in was added) fails here, asking for a reinstall."""
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    for group in plugins.GROUPS:
        installed = {name: point.value for name, point in plugins._scan()[0][group].items()}
        assert installed == declared.get(group, {}), f"{group}: reinstall (pip install -e .)"


def test_every_built_in_loads_from_its_own_module() -> None:
    from gainfarm.analytic.tuning.algorithms import nsga2, random
    from gainfarm.schemas import objectives
    from gainfarm.worker.trajectories import spiral

    assert plugins.load(plugins.ALGORITHMS, "nsga2") is nsga2.nsga2
    assert plugins.load(plugins.ALGORITHMS, "random") is random.UniformRandom
    assert plugins.load(plugins.TRAJECTORIES, "spiral") is spiral.KIND
    assert plugins.load(plugins.OBJECTIVES, "f_t") is objectives.f_t
    for group in plugins.GROUPS:
        for name in plugins.builtin_names(group):
            module = plugins._scan()[0][group][name].module
            assert plugins.load(group, name) is not None and module.startswith("gainfarm.")


def test_a_stale_installation_is_told_to_reinstall_gainfarm(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A built-in this source lists first that the installation's metadata lacks, as an editable
    install made before it was added would: the error says why, in one line."""
    order = {**plugins.ORDER, plugins.ALGORITHMS: ("nsga2", "cmaes")}
    monkeypatch.setattr(plugins, "ORDER", order)
    monkeypatch.setattr(plugins, "_found", None)
    assert "cmaes" not in plugins.builtin_names(plugins.ALGORITHMS)
    with pytest.raises(plugins.PluginError) as raised:
        plugins.load(plugins.ALGORITHMS, "cmaes")
    message = str(raised.value)
    assert "\n" not in message and "lacks its own cmaes" in message
    assert "reinstall gainfarm" in message


def test_the_plugin_name_rule_is_the_contracts() -> None:
    assert plugins.NAME_PATTERN == KIND_PATTERN


def test_importing_the_registry_loads_nothing_of_the_project_nor_the_metadata() -> None:
    code = (
        "import sys, gainfarm.plugins as p; "
        "print(sorted(m for m in sys.modules if m.startswith('gainfarm') or "
        "m == 'importlib.metadata'))"
    )
    shown = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert shown.stdout.strip() == "['gainfarm', 'gainfarm.plugins']"


def test_listing_every_groups_names_imports_no_plugin() -> None:
    """The built-ins' names come from gainfarm's metadata: no module of theirs is imported."""
    code = (
        "import sys, gainfarm.plugins as p; [p.names(g) for g in p.GROUPS]; "
        "print(sorted(m for m in sys.modules if m.startswith('gainfarm')))"
    )
    shown = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert shown.stdout.strip() == "['gainfarm', 'gainfarm.plugins']"


def test_a_plugin_registered_in_process_is_found_and_forgotten() -> None:
    def mean_error(log: object) -> float:
        return 0.0

    plugins.register(plugins.OBJECTIVES, "mean_error", mean_error)
    try:
        assert "mean_error" in plugins.names(plugins.OBJECTIVES)
        assert plugins.load(plugins.OBJECTIVES, "mean_error") is mean_error
        assert RunConfig(objectives=("mean_error", "f_t")).objectives == ("mean_error", "f_t")
    finally:
        plugins.unregister(plugins.OBJECTIVES, "mean_error")
    assert "mean_error" not in plugins.names(plugins.OBJECTIVES)


@pytest.mark.parametrize(
    ("group", "name", "message"),
    [
        (plugins.ALGORITHMS, "nsga2", "built-in"),
        (plugins.OBJECTIVES, "Peak", "lower-case"),
        (plugins.OBJECTIVES, "a/b", "lower-case"),
        ("gainfarm.samplers", "tpe", "no plug-in group"),
    ],
)
def test_register_refuses_a_built_in_name_a_bad_name_and_an_unknown_group(
    group: str, name: str, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        plugins.register(group, name, object())


def test_an_unknown_name_is_one_error_naming_group_name_and_what_there_is() -> None:
    with pytest.raises(plugins.PluginError) as raised:
        plugins.load(plugins.TRAJECTORIES, "lemniscate")
    message = str(raised.value)
    assert "\n" not in message
    assert "gainfarm.trajectories" in message and "'lemniscate'" in message
    assert "spiral, random, pyramid, fourier" in message


def test_a_run_config_names_only_what_this_installation_has() -> None:
    for fields, name in (
        ({"algorithm": "cmaes"}, "cmaes"),
        ({"objectives": ("f_acc", "jerk")}, "jerk"),
        ({"trajectories": (TrajectorySpec(kind="lemniscate"),)}, "lemniscate"),
    ):
        with pytest.raises(ValidationError, match=name):
            RunConfig(**fields)
    with pytest.raises(ValidationError, match="twice"):
        RunConfig(objectives=("f_t", "f_t"))


# --- installed: an entry point of each group ------------------------------------------------


def test_installed_plugins_are_listed_without_being_imported(installed: Path) -> None:
    assert "gainfarm_fixture" not in sys.modules
    assert "hill_climb" in plugins.names(plugins.ALGORITHMS)
    assert "circle" in plugins.names(plugins.TRAJECTORIES)
    assert {"peak_torque", "broken"} <= set(plugins.names(plugins.OBJECTIVES))
    assert "gainfarm_fixture" not in sys.modules
    assert plugins.load(plugins.TRAJECTORIES, "circle").__module__ == "gainfarm_fixture"


def test_a_third_partys_entry_point_with_a_built_ins_name_is_ignored(installed: Path) -> None:
    """The fixture declares its circle as "spiral" too: gainfarm's spiral is the one there is."""
    from gainfarm.worker.trajectories import spiral

    assert plugins.names(plugins.TRAJECTORIES).count("spiral") == 1
    assert plugins.load(plugins.TRAJECTORIES, "spiral") is spiral.KIND


def test_an_entry_point_that_fails_to_load_says_which_and_why(installed: Path) -> None:
    with pytest.raises(plugins.PluginError) as raised:
        plugins.load(plugins.OBJECTIVES, "broken")
    message = str(raised.value)
    assert "'broken'" in message and "gainfarm_fixture:no_such_objective" in message
    assert "failed to load" in message and "\n" not in message


def test_a_plugin_optimiser_resumes_from_its_checkpoint_exactly(
    installed: Path, tmp_path: Path
) -> None:
    """Its class is allowed in the checkpoint of a run that names it, and only there."""
    rng = np.random.default_rng(0)

    def generation(evolution: Evolution) -> None:
        evolution.ask()
        evolution.tell([tuple(point) for point in rng.uniform(0.01, 1.0, (4, 2))])

    whole = Evolution(4, seed=5, algorithm="hill_climb")
    resumed = Evolution(4, seed=5, algorithm="hill_climb")
    identity = RunIdentity.new()
    path = tmp_path / "checkpoint.pkl"
    for _ in range(3):
        state = rng.bit_generator.state
        generation(whole)
        rng.bit_generator.state = state
        generation(resumed)
        resumed = decode(encode(resumed, identity), path, identity, "hill_climb")
    assert resumed.ask() == whole.ask()
    assert resumed.front() == whole.front()
    for algorithm in (None, "nsga2"):
        with pytest.raises(CheckpointRefused, match=r"gainfarm_fixture\.HillClimb"):
            decode(encode(resumed, identity), path, identity, algorithm)


@pytest.mark.usefixtures("installed")
class TestTheFixturesOptimiserPassesTheKit(AlgorithmChecks):
    """A third party's optimiser, one module and one entry point, passes the checks gainfarm's
    own pass (gainfarm.testing.algorithms)."""

    algorithm = "hill_climb"


@pytest.mark.usefixtures("installed")
class TestTheFixturesTrajectoryKindPassesTheKit(TrajectoryChecks):
    """Its trajectory kind, the simple form (a path function), likewise."""

    spec = CIRCLE


def test_tuning_in_process_with_all_three(installed: Path, tmp_path: Path) -> None:
    run = tune(RunConfig(**WITH_ALL_THREE), tmp_path / "run", evaluator=InProcessEvaluator())
    front = run.front()
    assert front and run.state.evolution.algorithm_name == "hill_climb"
    # The second objective is the plug-in's, computed on the episode's log: the peak torque.
    member = front[0]
    log = run_episode(EpisodeSpec(gains=member.gains, trajectory=CIRCLE))
    assert member.named["peak_torque"] == float(np.max(np.abs(log.u))) != 0.0
    config = (tmp_path / "run" / "config.json").read_text()
    assert '"hill_climb"' in config and '"peak_torque"' in config and '"circle"' in config
    # Its name and unit travel from its declaration to every file, figure and report the run
    # writes: nothing calls it f_t, nor a torque change.
    directory = tmp_path / "run"
    front_csv = (directory / "front.csv").read_text()
    assert front_csv.splitlines()[0].endswith(",f_acc,peak_torque,diverged")
    assert (directory / "evaluated.csv").read_text().startswith("f_acc,peak_torque,torque_step,")
    assert ",best_f_acc,best_peak_torque," in (directory / "history.csv").read_text()
    assert '"peak_torque": ' in (directory / "front.json").read_text()
    report = (directory / "report.md").read_text()
    assert "| f_acc (mm) | peak_torque (N·m) |" in report
    assert "peak_torque is the largest torque commanded on any joint, in N·m" in report
    assert f"peak_torque {front[0].named['peak_torque']:.4g} N·m" in report
    for written in (front_csv, (directory / "evaluated.csv").read_text(), report):
        assert "f_t" not in written and "torque change" not in written
    figure = pareto_figure(front, run.state.evaluated, names=run.config.objectives)
    assert figure.axes[0].get_ylabel() == "peak_torque: largest torque commanded on any joint (N·m)"
    # Read back as it was written, by name, with no knowledge of the run but its files.
    record = read_run(directory)
    assert [m.named for m in record.front] == [m.named for m in front]
    assert record.evaluated == run.state.evaluated


def test_the_fixtures_objective_passes_the_conformance_kit(installed: Path) -> None:
    declared = check_objective(plugins.load(plugins.OBJECTIVES, "peak_torque"), "peak_torque")
    assert (declared.unit, declared.direction) == ("N·m", "minimise")


@pytest.mark.slow
def test_tuning_on_a_local_farm_gives_the_in_process_front(
    on_workers: Path, tmp_path: Path
) -> None:
    config = RunConfig(**WITH_ALL_THREE)
    here = tune(config, tmp_path / "here", evaluator=InProcessEvaluator()).front()
    farmed = tune(config, tmp_path / "farm", FarmOptions(workers=1)).front()
    assert [(m.gains, m.objectives) for m in farmed] == [(m.gains, m.objectives) for m in here]


@pytest.mark.slow
def test_a_worker_without_the_plugin_refuses_and_the_run_says_so(
    installed: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("PYTHONPATH", raising=False)  # the worker processes lack the plug-ins
    with pytest.raises(plugins.PluginError) as raised:
        tune(RunConfig(**WITH_ALL_THREE), tmp_path / "run", FarmOptions(workers=1))
    message = str(raised.value)
    assert "\n" not in message
    assert "refused job" in message and re.search(r"worker local-0-[0-9a-f]+ refused", message)
    assert "gainfarm.trajectories" in message and "'circle'" in message


def test_analytic_start_on_workers_without_the_plugin_is_one_line_and_resumable(
    installed: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The command line in this process (the plug-in on its path), its local worker without it."""
    monkeypatch.delenv("PYTHONPATH", raising=False)
    monkeypatch.chdir(tmp_path)
    options = ["--trajectory", "circle", "--duration", "3", "--pop", "4", "--generations", "1"]
    monkeypatch.setattr(sys, "argv", ["analytic", "start", "--local", *options, "--out", "run"])
    try:
        with pytest.raises(SystemExit) as exited:
            analytic_main()
    finally:
        interrupts.uninstall()  # the command took Ctrl-C over for its process: give it back
    error = capsys.readouterr().err.splitlines()[-1]
    assert exited.value.code == 2  # whichever local worker (one per core) took the job first
    assert re.match(r"analytic: error: worker local-\d+-[0-9a-f]+ refused", error), error
    assert "no plug-in named 'circle'" in error and error.endswith("then: analytic resume run")
    assert (tmp_path / "run" / "config.json").is_file()  # what it names resumes


@pytest.fixture
def refuser_and_able(
    installed: Path, broker: Broker, monkeypatch: pytest.MonkeyPatch
) -> Iterator[Broker]:
    """`broker` with two workers: "refuser", without the plug-ins, and "able", with them."""
    monkeypatch.delenv("PYTHONPATH", raising=False)
    workers = [spawn_worker(broker.endpoints[0], "refuser")]
    try:
        monkeypatch.setenv("PYTHONPATH", str(installed))
        workers.append(spawn_worker(broker.endpoints[0], "able"))
        wait_for(lambda: broker.status().worker_count == 2, 60, "the workers")
        yield broker
    finally:
        stop_workers(workers)


@pytest.mark.slow
def test_a_worker_without_the_plugin_beside_one_with_it_leaves_the_run_its_front(
    refuser_and_able: Broker, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Its refusals are no verdict on the run: each job it refuses runs on the other worker."""
    config = RunConfig(**WITH_ALL_THREE)
    here = tune(config, tmp_path / "here", evaluator=InProcessEvaluator()).front()
    tuning = TuningRun.create(tmp_path / "farm", config)
    with (
        caplog.at_level("WARNING", logger="gainfarm.analytic"),
        FarmClient(refuser_and_able.endpoints, "s", tmp_path / "farm", trusted=True) as farm,
    ):
        tuning.run(farm)
        done = {worker.name: worker.jobs_done for worker in farm.status().workers}
    farmed = [(m.gains, m.objectives) for m in tuning.front()]
    assert farmed == [(m.gains, m.objectives) for m in here]
    said = [record.getMessage() for record in caplog.records]
    assert any(
        re.match(r"worker refuser refused job \S+: gainfarm\.trajectories: .*'circle'", line)
        and line.endswith("; running it on another worker")
        for line in said
    ), said
    # Every job the refuser took it refused, all of the first generation: once it had refused
    # one, it was given no more that need the plug-in; every job ran on the other worker.
    refused = [line.split()[4] for line in said if line.startswith("worker refuser refused job")]
    assert refused and len(refused) == done["refuser"]
    assert all(job_id.startswith("g0000-") for job_id in refused), refused
    assert done["able"] == config.pop * config.generations
    tuning.close()


@pytest.mark.slow
def test_a_refusal_stops_the_run_when_this_process_lacks_the_plugin_too(
    refuser_and_able: Broker, installed: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Another worker could run the job; this process could not check it, nor run it itself."""
    monkeypatch.setattr(sys, "path", [entry for entry in sys.path if entry != str(installed)])
    monkeypatch.setattr(plugins, "_loaded", {})
    with pytest.raises(plugins.PluginError):
        plugins.load(plugins.TRAJECTORIES, "circle")  # lacking here
    specs = {f"j{n}": EpisodeSpec(gains=DEFAULT_GAINS, trajectory=CIRCLE) for n in range(4)}
    with FarmClient(refuser_and_able.endpoints, "s", tmp_path, trusted=True) as farm:
        farm.submit(specs)
        with pytest.raises(plugins.PluginError) as raised:
            list(farm.results(timeout=120))
    message = str(raised.value)
    assert "\n" not in message and message.startswith("worker refuser refused job j")
    assert "gainfarm.trajectories" in message and "'circle'" in message


@pytest.mark.parametrize(
    ("fields", "named"),
    [
        ({"trajectory": TrajectorySpec(kind="lemniscate")}, "gainfarm.trajectories: no plug-in"),
        ({"objectives": ("f_acc", "jerk")}, "gainfarm.objectives: no plug-in named 'jerk'"),
    ],
)
def test_a_job_naming_a_missing_plugin_is_refused_before_it_runs(fields: dict, named: str) -> None:
    outcome = simulate(EpisodeSpec(gains=DEFAULT_GAINS, **fields))
    assert outcome.status == JobStatus.refused
    assert named in outcome.reason and outcome.content == b"" and outcome.scores is None


# --- the contract: objectives named by the episode, scored from its log ---------------------


def test_an_episode_of_the_papers_objectives_has_the_json_it_had() -> None:
    """The fields objectives added are left out when they hold the paper's: a built-in job, its
    log's metadata and its scores are the bytes they were before plug-ins."""
    spec = EpisodeSpec(gains=DEFAULT_GAINS)
    assert "objectives" not in spec.model_dump_json()
    scores = simulate(EpisodeSpec(gains=DEFAULT_GAINS, trajectory=FOURIER)).scores
    assert scores is not None and "values" not in scores.model_dump_json()
    assert scores.objectives == (scores.f_acc, scores.f_t)


def test_a_plugin_objective_is_scored_from_the_log_in_its_place() -> None:
    def peak(log: object) -> float:
        return float(np.max(np.abs(log.u)))  # type: ignore[attr-defined]

    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=FOURIER, objectives=("peak", "f_acc"))
    log = run_episode(spec)
    scores = score(log, {"peak": peak})
    assert scores.objectives == (peak(log), scores.f_acc) and scores.values is not None
    with pytest.raises(ValueError, match="'peak'"):
        score(log)  # the contract loads no plug-in: it is given its function, or says so


def test_scores_pickled_before_objectives_could_be_chosen_read_back() -> None:
    scores = Scores(
        f_acc=0.01, f_t=3.0, max_error=0.02, saturated_fraction=0.0, diverged=False, ticks=9
    )
    state = scores.__getstate__()
    del state["__dict__"]["values"]  # a checkpoint's Scores from before `values`
    old = Scores.__new__(Scores)
    old.__setstate__(state)
    assert old == scores and old.objectives == (0.01, 3.0)


# --- an experiment ----------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.usefixtures("installed")
class TestTheFixturesExperimentPassesTheKit(ExperimentChecks):
    """A third party's experiment (gainfarm_fixture.seeds, its entry point in the fixture's
    pyproject.toml) through the kit its author runs: real episodes, in this process."""

    experiment = "seeds"
    options: ClassVar[dict[str, str]] = {"--runs": "2"}
    bad_options: ClassVar[dict[str, str]] = {"--runs": "0"}
