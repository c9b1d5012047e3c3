"""The gap between an arm and a plant: its logged episodes replayed through the plant.

A replay runs the logged episode's controller (its gains, its reference) on the plant, closed
loop, as the arm ran it; the simulation error is the RMS over ticks of the replayed measurement
less the logged one, per joint: of the joint angle q and of the joint torque. Beside it, the
episode's objectives as the plant predicts them and as the arm's log shows them.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gainfarm.schemas.episode import Scores
from gainfarm.schemas.episode_log import EpisodeLog


@dataclass(frozen=True)
class Gap:
    """One logged episode against its replay on one plant."""

    q: np.ndarray  # (7,) RMS of q error, rad
    torque: np.ndarray  # (7,) RMS of joint torque error, N·m
    f_acc: float  # the replay's (the plant's prediction), m
    f_t: float  # (N·m)²
    logged_f_acc: float  # the arm's
    logged_f_t: float

    @property
    def f_acc_error(self) -> float:
        """The prediction's error as a share of what the arm did."""
        return abs(self.f_acc - self.logged_f_acc) / self.logged_f_acc


def gap(logged: EpisodeLog, logged_scores: Scores, replay: EpisodeLog, scores: Scores) -> Gap:
    """How far `replay` (the episode on a plant) is from `logged` (the arm's)."""
    n = min(logged.ticks, replay.ticks)  # a replay that diverged stops early: its ticks count
    return Gap(
        q=_rms(replay.q[:n] - logged.q[:n]),
        torque=_rms(replay.tau[:n] - logged.tau[:n]),
        f_acc=scores.f_acc,
        f_t=scores.f_t,
        logged_f_acc=logged_scores.f_acc,
        logged_f_t=logged_scores.f_t,
    )


def _rms(error: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.square(error), axis=0))


def pooled(gaps: Sequence[Gap], attribute: str) -> np.ndarray:
    """Per joint RMS over episodes (each episode weighted alike)."""
    return np.sqrt(np.mean([np.square(getattr(g, attribute)) for g in gaps], axis=0))
