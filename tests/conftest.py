"""Shared fixtures: real episodes simulated in MuJoCo, kept short so the suite stays fast."""

import pytest

from schemas import EpisodeSpec, TrajectorySpec
from schemas.episode_log import EpisodeLog
from tests.helpers import TRACKING_GAINS, WEAK_GAINS
from worker.episode import run_episode


@pytest.fixture(scope="session")
def tracking_log() -> EpisodeLog:
    """A 2 s spiral tracked with stiff gains on the default (flexible) robot."""
    return run_episode(EpisodeSpec(gains=TRACKING_GAINS, trajectory=TrajectorySpec(duration=2.0)))


@pytest.fixture(scope="session")
def diverged_log() -> EpisodeLog:
    """Gains far too soft to hold the arm up: it falls and the episode is stopped early."""
    return run_episode(EpisodeSpec(gains=WEAK_GAINS, trajectory=TrajectorySpec(duration=2.0)))
