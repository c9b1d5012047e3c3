"""Tuning runs on real farms with workers that lie (tests/analytic/liar.py, real processes):
whatever they do, the run reports the front an honest farm gives with the same seed, or
refuses a member and says why; never a false row reported as validated.

The calm front is the run's in this process (trusted, nothing to referee): episodes are
deterministic, so an honest farm's is the same, bit for bit."""

import subprocess
import sys
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import spawn_worker, stop_workers
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import read_front_json, read_validation
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.broker.service import Broker
from gainfarm.schemas.trajectory import TrajectorySpec
from tests.helpers import wait_for

CONFIG = RunConfig(
    pop=8,
    generations=3,
    seed=7,
    trajectories=(TrajectorySpec(kind="fourier", duration=0.4),),
)


def spawn(endpoint: str, name: str) -> subprocess.Popen:
    """An honest worker ("h…"), or a rogue of the kind its name starts with."""
    for prefix, how in (("forger", "--forge"), ("saboteur", "--sabotage")):
        if name.startswith(prefix):
            command = [sys.executable, "-m", "tests.analytic.liar", endpoint, name, how]
            return subprocess.Popen(command, stdin=subprocess.DEVNULL)
    assert name.startswith("h"), f"an honest worker's name starts with h, not {name!r}"
    return spawn_worker(endpoint, name)


@pytest.fixture(scope="module")
def calm(tmp_path_factory: pytest.TempPathFactory) -> TuningRun:
    directory = tmp_path_factory.mktemp("calm") / "run"
    tuning = TuningRun.create(directory, CONFIG)
    tuning.run(InProcessEvaluator(directory))
    return tuning


def farm_run(broker: Broker, names: list[str], directory: Path, config: RunConfig) -> TuningRun:
    workers = [spawn(broker.endpoints[0], name) for name in names]
    try:
        wait_for(lambda: broker.status().worker_count == len(names), 30, "the workers")
        tuning = TuningRun.create(directory, config)
        with FarmClient(broker.endpoints, "rogue", directory, keep_logs=False) as farm:
            tuning.run(farm)
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
            assert episode.check in {"refereed", "spot-checked"}
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
