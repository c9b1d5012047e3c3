"""A local farm only its own workers can join (analytic/evaluators/local.py): its broker listens
on a Unix socket in a directory of this user's alone, so a process of another user cannot reach
it; and a process of this user that does (a forger, tests/analytic/liar.py, given the farm's
endpoint) has its results refused by the run, which reports the calm front (same seed) and names
only the farm's own workers. Real processes, real Zenoh.

The tests run as root (which the kernel lets through any directory's permissions): the stranger
is a process that drops to `nobody` before it connects."""

import logging
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from gainfarm import plugins
from gainfarm.analytic.compose import FarmOptions, tune
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import LocalFarm, robot_options, stop_workers
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import read_front_json
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.schemas.trajectory import TrajectorySpec
from tests.helpers import short_spec, wait_for

CONFIG = RunConfig(
    pop=4,
    generations=2,
    seed=11,
    trajectories=(TrajectorySpec(kind="fourier", duration=0.4),),
)
NOBODY = 65534  # uid and gid of `nobody` (and `nogroup`) on Debian

# Imports first (the interpreter and the venv may be out of another user's reach), then, with
# `drop`, becomes nobody, then tries to join the farm: prints "joined" and whether the broker's
# liveliness token is seen, or "refused" and why.
STRANGER = f"""
import os, sys
from gainfarm.edges.transport import open_session, token_held
from gainfarm.schemas import keys
endpoint, drop = sys.argv[1], sys.argv[2] == "drop"
if drop:
    os.setgroups([])
    os.setgid({NOBODY})
    os.setuid({NOBODY})
try:
    session = open_session("client", connect=[endpoint])
except ConnectionError as error:
    print("refused", os.getuid(), error)
else:
    print("joined", os.getuid(), token_held(session, keys.ALIVE_BROKER, timeout=5.0))
    session.close()
"""


def stranger(endpoint: str, drop: bool) -> str:
    command = [sys.executable, "-c", STRANGER, endpoint, "drop" if drop else "stay"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, check=True)
    return done.stdout.strip()


@pytest.fixture(scope="module")
def calm(tmp_path_factory: pytest.TempPathFactory) -> TuningRun:
    return tune(CONFIG, tmp_path_factory.mktemp("calm") / "run", evaluator=InProcessEvaluator())


@pytest.mark.slow
@pytest.mark.skipif(os.geteuid() != 0, reason="becoming another user takes root")
def test_another_user_cannot_reach_a_local_farm_its_own_workers_serve(tmp_path: Path) -> None:
    with LocalFarm(workers=1) as farm:
        endpoint = farm.ready()
        assert endpoint.startswith("unixsock-stream/") and "tcp/" not in endpoint
        directory = Path(farm.directory)
        mode = directory.stat()
        assert stat.S_IMODE(mode.st_mode) == 0o700 and mode.st_uid == os.geteuid()
        # The same process, as this user: it joins and sees the broker (the check can fail).
        assert stranger(endpoint, drop=False) == "joined 0 True"
        # As nobody: the kernel refuses its connect(), so it never reaches the broker.
        refused = stranger(endpoint, drop=True)
        assert refused.startswith(f"refused {NOBODY} cannot open a Zenoh client session"), refused
        # Meanwhile the farm's own workers work.
        with FarmClient([endpoint], "s", tmp_path, own_workers=farm.names) as client:
            client.submit({"j": short_spec(duration=0.3)})
            (result,) = client.results(timeout=120)
        assert result.status == "ok" and result.worker in farm.names
    assert not directory.exists()  # its socket goes with the farm


def test_a_local_farms_worker_names_are_its_own() -> None:
    with LocalFarm(workers=2) as first, LocalFarm(workers=2) as second:
        assert len(set(first.names)) == 2 and not set(first.names) & set(second.names)
        assert all(name.startswith("local-") for name in first.names)
        assert first.endpoint != second.endpoint


@pytest.mark.slow
def test_a_forger_of_this_user_on_a_local_farm_is_refused_and_the_front_is_the_calm_one(
    calm: TuningRun, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    farm = LocalFarm(workers=1)
    forger = None
    try:
        endpoint = farm.ready()
        command = [sys.executable, "-m", "tests.analytic.liar", endpoint, "forger", "--forge"]
        forger = subprocess.Popen(command, stdin=subprocess.DEVNULL)
        with FarmClient([endpoint], "watch", tmp_path / "watch") as watching:
            wait_for(lambda: watching.capacity == 2, 60, "the forger to join")
        with caplog.at_level(logging.WARNING, logger="gainfarm.analytic"):
            tuning = tune(
                CONFIG, tmp_path / "run", FarmOptions(local=farm)
            )  # as `analytic start` runs it
    finally:
        farm.stop()
        if forger is not None:
            stop_workers([forger])
    refusals = [r.getMessage() for r in caplog.records if "did not start" in r.getMessage()]
    assert refusals == ["result from worker forger, which this local farm did not start: refused"]
    assert [(m.gains, m.objectives) for m in tuning.front()] == [
        (m.gains, m.objectives) for m in calm.front()
    ]
    members = read_front_json(tuning.directory / "front.json")
    ran = {episode.worker for member in members for episode in member.episodes}
    assert ran and ran <= set(farm.names)
    provenance = (tuning.directory / "provenance.csv").read_text()
    assert "forger" not in provenance and farm.names[0] in provenance


def test_a_shipped_arms_workers_are_told_no_description_file() -> None:
    # A worker has every shipped arm (its plug-ins): only a described arm's file is passed on.
    for name in plugins.builtin_names(plugins.ROBOTS):
        assert robot_options(name) == ()
    assert robot_options(None) == ()
