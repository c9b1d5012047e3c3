import pytest

from schemas.objectives import DIVERGED_TICK_ERROR, score
from schemas.robot import TORQUE_LIMITS
from tests.helpers import crafted_log


def test_objectives_match_hand_computed_values():
    scores = score(crafted_log())
    assert scores.f_acc == pytest.approx((0.3 + 0.4 + 0.0) / 3)
    assert scores.f_t == pytest.approx((9.0 + 1600.0) / 3)  # u_0 = u_1: no change at the start
    assert scores.max_error == pytest.approx(0.4)
    assert scores.saturated_fraction == pytest.approx(1 / 3)
    assert not scores.diverged and scores.ticks == 3


def test_a_diverged_episode_is_charged_the_worst_for_every_tick_it_missed():
    scores = score(crafted_log(planned=5, diverged=True))
    worst_change = sum((2 * limit) ** 2 for limit in TORQUE_LIMITS)
    assert scores.f_acc == pytest.approx((0.7 + 2 * DIVERGED_TICK_ERROR) / 5)
    assert scores.f_t == pytest.approx((1609.0 + 2 * worst_change) / 5)
    assert scores.diverged


def test_diverged_episodes_score_worse_than_finished_ones(tracking_log, diverged_log):
    finished, diverged = score(tracking_log), score(diverged_log)
    assert diverged.f_acc > finished.f_acc and diverged.f_t > finished.f_t
