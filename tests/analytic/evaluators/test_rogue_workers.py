"""Tuning runs on real farms with workers that lie (tests/analytic/liar.py, real processes):
whatever they do, the run reports the front an honest farm gives with the same seed, or
refuses a member and says why; never a false row reported as validated.

The calm front is the run's in this process (trusted, nothing to referee): episodes are
deterministic, so an honest farm's is the same, bit for bit."""

import itertools
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import spawn_worker, stop_workers
from gainfarm.analytic.evaluators.replication import sized_rate, spot_checked
from gainfarm.analytic.tuning.check import read_check, run_check
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.plants import HELD_OUT, variants
from gainfarm.analytic.tuning.records import read_baseline, read_front_json, read_validation
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.analytic.view.run_report import write_run_report
from gainfarm.broker.service import Broker
from gainfarm.schemas.robot import REALISTIC_PLANT
from gainfarm.schemas.trajectory import TrajectorySpec
from tests.helpers import wait_for

CONFIG = RunConfig(
    pop=8,
    generations=3,
    seed=7,
    trajectories=(TrajectorySpec(kind="fourier", duration=0.4),),
)


def spawn(endpoint: str, name: str, *flags: str) -> subprocess.Popen:
    """An honest worker ("h…"), or a rogue of the kind its name starts with (or `flags` say:
    tests.analytic.liar's)."""
    for prefix, how in (("forger", "--forge"), ("saboteur", "--sabotage"), ("rogue", "")):
        if name.startswith(prefix):
            chosen = list(flags) or [how]
            command = [sys.executable, "-m", "tests.analytic.liar", endpoint, name, *chosen]
            return subprocess.Popen(command, stdin=subprocess.DEVNULL)
    assert name.startswith("h"), f"an honest worker's name starts with h, not {name!r}"
    return spawn_worker(endpoint, name)


@pytest.fixture(scope="module")
def calm(tmp_path_factory: pytest.TempPathFactory) -> TuningRun:
    directory = tmp_path_factory.mktemp("calm") / "run"
    tuning = TuningRun.create(directory, CONFIG)
    tuning.run(InProcessEvaluator(directory))
    return tuning


def farm_run(
    broker: Broker,
    names: list[str],
    directory: Path,
    config: RunConfig,
    flags: tuple[str, ...] = (),
    spot_key: bytes | None = None,
    then: Callable[[TuningRun, Evaluator], None] = lambda *_: None,
) -> TuningRun:
    """A run on a farm of `names` (a rogue's given `flags`), with `spot_key` if given; `then`
    runs on the same farm after the evolution (the baseline, the check)."""
    workers = [
        spawn(broker.endpoints[0], name, *(flags if name.startswith("rogue") else ()))
        for name in names
    ]
    try:
        wait_for(lambda: broker.status().worker_count == len(names), 30, "the workers")
        tuning = TuningRun.create(directory, config)
        if spot_key is not None:
            tuning.state.spot_key = spot_key
        with FarmClient(broker.endpoints, "rogue", directory, keep_logs=False) as farm:
            tuning.run(farm)
            then(tuning, farm)
        return tuning
    finally:
        stop_workers(workers)


def assert_calm_front(tuning: TuningRun, calm: TuningRun, rogues: set[str]) -> None:
    assert [(m.gains, m.objectives) for m in tuning.front()] == [
        (m.gains, m.objectives) for m in calm.front()
    ]
    assert set(tuning.replication.dissenters) == rogues
    members = read_front_json(tuning.directory / "front.json")
    assert [m.objectives for m in members] == [m.objectives for m in calm.front()]
    for member in members:  # every row checked: an honest worker's, or the referee's own
        assert member.episodes
        for episode in member.episodes:
            assert episode.check in {"refereed", "spot-checked", "failure-checked"}
            if episode.worker in rogues:  # caught on it: the referee's run stands
                assert episode.ruling == "contradicted"
            else:
                assert episode.worker.startswith("h") and episode.ruling == "agreed"
    validation = read_validation(tuning.directory / "front.json")
    assert validation is not None and set(validation.distrusted) == rogues


@pytest.mark.slow
@pytest.mark.parametrize(
    "names",
    [["forger", "h1"], ["forger1", "h1", "forger2"]],
    ids=["one-forger-of-two", "two-colluding-forgers-and-one-honest"],
)
def test_forgers_cannot_put_a_false_row_in_the_front(
    broker: Broker, calm: TuningRun, names: list[str], tmp_path: Path
) -> None:
    # The front alone refereed: a spot check that caught a forger on its first episode would
    # leave nothing to start again for (the saboteur's test is the spot checks').
    front_only = CONFIG.model_copy(update={"spot_checks": 0.0})
    tuning = farm_run(broker, names, tmp_path / "run", front_only)
    rogues = {name for name in names if name.startswith("forger")}
    assert tuning.state.rewinds >= 1
    assert_calm_front(tuning, calm, rogues)


@pytest.mark.slow
def test_a_saboteur_is_caught_by_spot_checks_and_the_front_is_the_calm_one(
    broker: Broker, calm: TuningRun, tmp_path: Path
) -> None:
    # Its ~12 episodes, each drawn at 0.5: missed with probability 2^-12, and then the test
    # fails on its front (steered) or its dissenters (none), never passes falsely.
    config = CONFIG.model_copy(update={"spot_checks": 0.5})
    tuning = farm_run(broker, ["saboteur", "h1"], tmp_path / "run", config)
    assert tuning.replication.spot_checked > 0
    assert "scores its log does not have" in tuning.replication.dissenters["saboteur"]
    assert_calm_front(tuning, calm, {"saboteur"})


@pytest.mark.slow
def test_the_workers_left_to_trust_are_counted_by_name_even_when_a_caught_one_has_gone(
    broker: Broker, tmp_path: Path
) -> None:
    workers = {name: spawn(broker.endpoints[0], name) for name in ("h1", "h2")}
    try:
        wait_for(lambda: broker.status().worker_count == 2, 30, "the workers")
        with FarmClient(broker.endpoints, "count", tmp_path, keep_logs=False) as farm:
            assert farm.trusted_capacity == 2
            farm.distrust("h1")
            farm.distrust("gone")  # caught, then left the farm: no longer counted at all
            assert farm.trusted_capacity == 1 and farm.capacity == 2
            stop_workers([workers.pop("h2")])
            wait_for(lambda: farm.trusted_capacity == 0, 30, "h2 to leave")
    finally:
        stop_workers(list(workers.values()))


def good_f_acc(calm: TuningRun) -> float:
    """What a rogue counts as a good candidate's episode: an f_acc no worse than three quarters
    of the calm run's (most of them, so each rogue surely runs some, and every front member)."""
    scores = [
        ran.scores.f_acc
        for episodes in calm.state.provenance.values()
        for ran in episodes
        if ran.scores is not None
    ]
    return float(np.quantile(scores, 0.75))


@pytest.mark.slow
def test_a_worker_that_says_every_good_candidate_failed_is_named_and_the_front_is_the_calm_one(
    broker: Broker, calm: TuningRun, tmp_path: Path
) -> None:
    flags = ("--fail-good", repr(good_f_acc(calm)))
    tuning = farm_run(broker, ["rogue", "h1"], tmp_path / "run", CONFIG, flags)
    assert tuning.replication.failures_checked > 0
    assert "failed job" in tuning.replication.dissenters["rogue"]
    assert "that the referee ran to scores" in tuning.replication.dissenters["rogue"]
    # Whether the evolution had to start again depends on which jobs the farm gave the rogue:
    # caught on its first result, the run holds nothing of it to forget (no rewind); caught
    # later, it does. Either way the run ends as the calm one.
    assert_calm_front(tuning, calm, {"rogue"})


def every_job_drawn(config: RunConfig, workers: int) -> bytes:
    """A spot key that draws, at the rate sized for `config` on `workers`, every episode of the
    run's first pass (before any rewind): a lie told there is caught, whoever runs it."""
    rate = sized_rate(config.pop * config.generations / workers)
    assert rate < 1  # sized, not every episode by definition: the key is what draws them
    jobs = [
        f"g{generation:04d}-c{index:03d}-t0"
        for generation in range(config.generations)
        for index in range(config.pop)
    ]
    for number in itertools.count():
        key = f"key-{number}".encode()
        if all(spot_checked(key, job, rate) for job in jobs):
            return key
    raise AssertionError("unreachable")


@pytest.mark.slow
def test_a_saboteur_of_good_candidates_is_caught_at_the_sized_rate(
    broker: Broker, calm: TuningRun, tmp_path: Path
) -> None:
    # CONFIG's spot checks are the default: sized for its 24 episodes over 2 workers.
    assert CONFIG.spot_checks is None
    flags = ("--sabotage-good", repr(good_f_acc(calm)))
    key = every_job_drawn(CONFIG, 2)
    tuning = farm_run(broker, ["rogue", "h1"], tmp_path / "run", CONFIG, flags, key)
    assert tuning.state.spot_rate == sized_rate(12)
    assert "scores its log does not have" in tuning.replication.dissenters["rogue"]
    caught_by = {
        check for check, ruling, worker in tuning.state.checks.values() if ruling == "contradicted"
    }
    assert caught_by == {"spot-checked"}  # as its results returned, not on the front
    assert_calm_front(tuning, calm, {"rogue"})
    validation = read_validation(tuning.directory / "front.json")
    assert validation is not None and validation.spot_check_rate == sized_rate(12)
    assert "caught with probability 0.99" in validation.spot_check_guarantee


CHECKED = CONFIG.model_copy(
    update={
        "trajectories": (
            TrajectorySpec(kind="fourier", duration=0.4),
            TrajectorySpec(kind="fourier", duration=0.4, seed=1),
        ),
        "check_plants": variants(REALISTIC_PLANT, 3, seed=0, stream=HELD_OUT),
    }
)


def baseline_and_check(tuning: TuningRun, evaluator: Evaluator) -> None:
    tuning.baseline(evaluator)
    run_check(tuning, evaluator)
    write_run_report(tuning, figures=False)


def advice_line(tuning: TuningRun) -> str:
    """report.md's first line after its title: the advice."""
    return (tuning.directory / "report.md").read_text().splitlines()[2]


@pytest.mark.slow
def test_a_forger_of_the_default_gains_changes_neither_the_baseline_nor_the_advice(
    broker: Broker, tmp_path: Path
) -> None:
    calm = TuningRun.create(tmp_path / "calm", CHECKED)
    here = InProcessEvaluator(calm.directory)
    calm.run(here)
    baseline_and_check(calm, here)
    tuning = farm_run(
        broker,
        ["rogue", "h1"],
        tmp_path / "run",
        CHECKED,
        ("--forge-defaults",),
        then=baseline_and_check,
    )
    assert "rogue" in tuning.replication.dissenters
    assert tuning.replication.baseline + tuning.replication.held_out > 0
    told, truth = read_baseline(tuning.directory / "baseline.json"), calm.baseline()
    assert truth is not None and (told.f_acc, told.f_t) == (truth.f_acc, truth.f_t)
    assert [e["scores"] for e in told.episodes] == [e["scores"] for e in truth.episodes]
    assert advice_line(tuning) == advice_line(calm)
    checked, calm_checked = read_check(tuning.directory), read_check(calm.directory)
    assert checked is not None and calm_checked is not None
    assert checked["advice"] == calm_checked["advice"]
    assert checked["controllers"] == calm_checked["controllers"]
    # --keep front (the default): the referee's logs of the default gains' and the check's
    # episodes are not kept; episodes/ holds the front's logs alone.
    assert tuning.config.keep == "front"
    kept = {Path(log).name for member in tuning.front() for log in member.logs}
    assert {path.name for path in (tuning.directory / "episodes").iterdir()} == kept
