import numpy as np
import pytest

from analytic.objectives import DIVERGED_TICK_ERROR, score
from schemas import EpisodeMetadata, EpisodeSpec, PDGains
from schemas.episode_log import EpisodeLog

LIMITS = (320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)


def crafted_log(planned: int = 3, diverged: bool = False) -> EpisodeLog:
    """Three ticks with errors 0.3, 0.4 and 0 m and torque steps small enough to add by hand."""
    tau = np.zeros((3, 7))
    tau[1, 0] = 3.0  # step 1: (3)² = 9
    tau[2, 0], tau[2, 6] = 3.0, 40.0  # step 2: (40)² = 1600, and A7 at its limit
    ee_des = np.zeros((3, 3))
    ee = np.array([[0.3, 0.0, 0.0], [0.0, 0.4, 0.0], [0.0, 0.0, 0.0]])
    zeros = np.zeros((3, 7))
    metadata = EpisodeMetadata(
        spec=EpisodeSpec(gains=PDGains(kp=(1,) * 7, kd=(1,) * 7)),
        ticks_planned=planned,
        ticks_run=3,
        torque_limits=LIMITS,
        diverged=diverged,
        versions={},
    )
    return EpisodeLog(
        t=np.arange(3) * 0.002,
        q=zeros,
        qd=zeros,
        tau=tau,
        q_des=zeros,
        qd_des=zeros,
        ee=ee,
        ee_des=ee_des,
        metadata=metadata,
    )


def test_objectives_match_hand_computed_values():
    scores = score(crafted_log())
    assert scores.f_acc == pytest.approx((0.3 + 0.4 + 0.0) / 3)
    assert scores.f_t == pytest.approx((9.0 + 1600.0) / 3)  # u_0 = u_1: no change at the start
    assert scores.max_error == pytest.approx(0.4)
    assert scores.saturated_fraction == pytest.approx(1 / 3)
    assert not scores.diverged and scores.ticks == 3


def test_a_diverged_episode_is_charged_the_worst_for_every_tick_it_missed():
    scores = score(crafted_log(planned=5, diverged=True))
    worst_change = sum((2 * limit) ** 2 for limit in LIMITS)
    assert scores.f_acc == pytest.approx((0.7 + 2 * DIVERGED_TICK_ERROR) / 5)
    assert scores.f_t == pytest.approx((1609.0 + 2 * worst_change) / 5)
    assert scores.diverged


def test_diverged_episodes_score_worse_than_finished_ones(tracking_log, diverged_log):
    finished, diverged = score(tracking_log), score(diverged_log)
    assert diverged.f_acc > finished.f_acc and diverged.f_t > finished.f_t
