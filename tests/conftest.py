"""Shared fixtures: real episodes simulated in MuJoCo, kept short so the suite stays fast."""

import signal
from collections.abc import Iterator

import pytest
import zenoh

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.service import Broker
from gainfarm.edges.transport import open_session
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.robot import PLAIN_PLANT
from gainfarm.worker.episode import run_episode
from tests.helpers import TRACKING_GAINS, WEAK_GAINS


@pytest.fixture(scope="session")
def tracking_log() -> EpisodeLog:
    """A 3 s spiral tracked with stiff gains on the default (realistic, flexible) robot."""
    return run_episode(EpisodeSpec(gains=TRACKING_GAINS, trajectory=TrajectorySpec(duration=3.0)))


@pytest.fixture(scope="session")
def diverged_log() -> EpisodeLog:
    """Gains far too soft to hold the arm up without the robot's gravity compensation (a plain
    torque interface): it falls and the episode is stopped early."""
    spec = EpisodeSpec(gains=WEAK_GAINS, trajectory=TrajectorySpec(duration=3.0), plant=PLAIN_PLANT)
    return run_episode(spec)


@pytest.fixture
def broker() -> Iterator[Broker]:
    """A broker (a Zenoh router) on a free loopback port, with multicast scouting off."""
    with Broker([f"tcp/127.0.0.1:{free_port()}"], lease_seconds=30.0) as running:
        yield running


@pytest.fixture
def session(broker: Broker) -> Iterator[zenoh.Session]:
    """A plain client session connected to `broker`, for playing any part by hand."""
    client = open_session("client", connect=broker.endpoints)
    yield client
    client.close()


@pytest.fixture(scope="session", autouse=True)
def ctrl_c_reaches_the_processes_tests_start() -> None:
    """Tests press Ctrl-C (SIGINT) on the processes they start, as a terminal does on its
    foreground job. A suite a shell started in the background has SIGINT ignored, and its
    children would inherit that (gainfarm, as Python, leaves an ignored SIGINT ignored): give
    it back its default, which a child does not inherit but starts with."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(autouse=True)
def ctrl_c_handler_left_as_found() -> Iterator[None]:
    """A test that takes Ctrl-C over in this process (a command line run in-process installs
    cli.interrupts) gives it back: the next test starts with the handler this one found."""
    before = signal.getsignal(signal.SIGINT)
    yield
    after = signal.getsignal(signal.SIGINT)
    assert after is before, f"the test left SIGINT's handler changed: {after!r}, was {before!r}"
