import dataclasses

import numpy as np
import pytest

from gainfarm import plugins
from gainfarm.schemas.episode import Scores
from gainfarm.schemas.objectives import (
    DIVERGED_TICK_ERROR,
    MAXIMISE,
    NO_EPISODE,
    Objective,
    balancing_weights,
    f_t_joint,
    joint_weights,
    no_episode,
    objectives,
    plant_scales,
    score,
)
from gainfarm.schemas.robot import TORQUE_LIMITS
from gainfarm.testing.objectives import ObjectiveTests
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


def test_the_per_joint_torque_measure_weighs_each_joints_change_by_its_limit():
    weights = joint_weights(TORQUE_LIMITS)
    assert weights == pytest.approx([(320 / limit) ** 2 for limit in TORQUE_LIMITS])
    # 3 N·m on A1 (limit 320) counts as it is; 40 N·m on A7 (limit 40) 64 times over.
    log = crafted_log()
    assert f_t_joint(log) == pytest.approx((9.0 + 64 * 1600.0) / 3)
    assert f_t_joint(log) >= score(log).f_t  # every weight at least 1
    # A run names it as its second objective: the scores carry it, f_t stays the paper's.
    named = log.metadata.spec.model_copy(update={"objectives": ("f_acc", "f_t_joint")})
    metadata = log.metadata.model_copy(update={"spec": named})
    scores = score(dataclasses.replace(log, metadata=metadata))
    assert scores.objectives == (scores.f_acc, f_t_joint(log))
    assert scores.f_t == pytest.approx((9.0 + 1600.0) / 3)
    # A diverged episode's missing ticks are each every joint's swing from limit to limit.
    diverged = crafted_log(planned=5, diverged=True)
    worst = sum(w * (2 * limit) ** 2 for w, limit in zip(weights, TORQUE_LIMITS, strict=True))
    assert f_t_joint(diverged) == pytest.approx((3 * f_t_joint(log) + 2 * worst) / 5)


def test_a_six_joint_log_is_scored_by_its_own_limits():
    """A UR5e-like log (6 joints, its limits in its metadata, as the worker writes them): the
    torque measures and the speed are shares of its own limits, hand computed."""
    torque, speed = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0), (3.0,) * 6
    names = ("j1", "j2", "j3", "j4", "j5", "j6")
    log = crafted_log()
    u = np.zeros((3, 6))
    u[1, 0], u[2, 5] = 15.0, 28.0  # 0.1 of j1's limit, then j6 from 0 to its limit
    qd = np.zeros((3, 6))
    qd[1, 3] = 1.5  # half j4's speed limit
    metadata = log.metadata.model_copy(
        update={
            "spec": log.metadata.spec.model_copy(
                update={"gains": log.metadata.spec.gains.model_copy(update={"kp": (1,) * 6})}
            ),
            "torque_limits": torque,
            "speed_limits": speed,
            "joint_names": names,
        }
    )
    six = dataclasses.replace(
        log,
        u=u,
        tau=u,
        qd=qd,
        q=qd * 0,
        theta=qd * 0,
        theta_d=qd * 0,
        q_des=qd * 0,
        qd_des=qd * 0,
        metadata=metadata,
    )
    scores = score(six)
    assert scores.f_t == pytest.approx((15.0**2 + 15.0**2 + 28.0**2) / 3)
    assert scores.torque_step == pytest.approx(1.0)  # j6: its whole limit in one tick
    assert scores.speed == pytest.approx(0.5)
    assert scores.saturated_fraction == pytest.approx(1 / 3)
    # f_t_joint weighs j6 by (150 / 28)²: its step counts as 28 · 150 / 28 = 150 N·m.
    assert f_t_joint(six) == pytest.approx((15.0**2 + 15.0**2 + 150.0**2) / 3)


def test_diverged_episodes_score_worse_than_finished_ones(tracking_log, diverged_log):
    finished, diverged = score(tracking_log), score(diverged_log)
    assert diverged.f_acc > finished.f_acc and diverged.f_t > finished.f_t


def scores(f_acc: float, f_t: float) -> Scores:
    return Scores(
        f_acc=f_acc, f_t=f_t, max_error=f_acc, saturated_fraction=0.0, diverged=False, ticks=1
    )


def test_a_candidates_objectives_are_the_plain_means_unless_weighted():
    both = [scores(0.01, 1.0), scores(0.03, 40.0)]
    assert objectives(both) == pytest.approx((0.02, 20.5))
    assert objectives(both, [(3.0, 1.0), (1.0, 1.0)]) == pytest.approx((0.015, 20.5))
    assert objectives([scores(0.01, 1.0), None]) == NO_EPISODE
    with pytest.raises(ValueError, match="1 objective weights for 2 trajectories"):
        objectives(both, [(1.0, 1.0)])


def test_balanced_weights_make_every_trajectory_count_alike_at_the_reference():
    # A pyramid whose f_t is 40 times the spiral's: unweighted it is 98 % of the mean f_t.
    reference = [(0.01, 1.0), (0.02, 40.0)]
    weights = balancing_weights(reference)
    w = np.array(weights)
    assert w.sum(axis=0) == pytest.approx([1.0, 1.0])
    shares = w * np.array(reference)  # each trajectory's part of the weighted mean
    assert shares[0] == pytest.approx(shares[1])
    # At the reference, the weighted objectives are the harmonic means, in the same units.
    assert objectives([scores(*point) for point in reference], weights) == pytest.approx(
        (2 / (1 / 0.01 + 1 / 0.02), 2 / (1 / 1.0 + 1 / 40.0))
    )


def test_plant_scales_make_every_plant_count_alike_at_the_reference():
    # Two trajectories on three plants each (the nominal first): the reference's objectives.
    reference = [(0.002, 0.1), (0.016, 0.2), (0.004, 0.05), (0.01, 1.0), (0.01, 2.0), (0.02, 4.0)]
    scales = plant_scales(reference, 3)
    at_reference = objectives([scores(*p) for p in reference], None, 3, "worst", scales)
    assert at_reference == pytest.approx((np.mean([0.002, 0.01]), np.mean([0.1, 1.0])))
    # Twice as good as the reference on a plant where it is worst counts as the nominal's half.
    better = [(0.002, 0.1), (0.008, 0.1), (0.004, 0.05), (0.01, 1.0), (0.01, 2.0), (0.02, 4.0)]
    halved = objectives([scores(*p) for p in better], None, 3, "worst", scales)
    assert halved == pytest.approx(at_reference)  # the worst is still another plant's
    worse = [(0.002, 0.1), (0.032, 0.2), (0.004, 0.05), (0.01, 1.0), (0.01, 2.0), (0.02, 4.0)]
    doubled = objectives([scores(*p) for p in worse], None, 3, "worst", scales)
    assert doubled[0] == pytest.approx((2 * 0.002 + 0.01) / 2)  # its plant at twice nominal
    # A plant the reference did not finish (nan) or scored 0 on is left as it is.
    assert plant_scales([(0.002, 0.1), (float("nan"), 0.0)], 2) == ((1.0, 1.0), (1.0, 1.0))
    with pytest.raises(ValueError, match="2 plant scales for 3 episodes"):
        objectives([scores(0.01, 1.0)] * 3, None, 3, "worst", scales[:2])


@pytest.mark.parametrize("reference", [[], [(0.01, 0.0)], [(0.01, float("nan"))], [(-1, 1)]])
def test_balancing_needs_a_positive_finite_reference(reference):
    with pytest.raises(ValueError, match="finite, positive"):
        balancing_weights(reference)


# --- the built-ins through the conformance kit a plug-in's author runs ------------------------


class TestFAcc(ObjectiveTests):
    objective = plugins.load(plugins.OBJECTIVES, "f_acc")
    name = "f_acc"


class TestFT(ObjectiveTests):
    objective = plugins.load(plugins.OBJECTIVES, "f_t")
    name = "f_t"


class TestFTJoint(ObjectiveTests):
    objective = plugins.load(plugins.OBJECTIVES, "f_t_joint")
    name = "f_t_joint"


def test_the_papers_no_episode_scores_are_its_objectives_declarations() -> None:
    declared = [plugins.load(plugins.OBJECTIVES, name) for name in ("f_acc", "f_t")]
    assert no_episode(declared) == NO_EPISODE == (10.0, 1e12)
    assert [o.label for o in declared] == ["f_acc (m)", "f_t ((N·m)²)"]


def test_a_maximised_plugin_is_told_negated_and_an_episode_missing_scores_the_runs_worst() -> None:
    log = crafted_log()
    most = Objective("most", "N·m", MAXIMISE, "largest torque", -1.0, lambda log: 40.0)
    named = log.metadata.spec.model_copy(update={"objectives": ("f_acc", "most")})
    metadata = log.metadata.model_copy(update={"spec": named})
    scores = score(dataclasses.replace(log, metadata=metadata), {"most": most})
    assert scores.objectives == (scores.f_acc, -40.0)
    run = no_episode([plugins.load(plugins.OBJECTIVES, "f_acc"), most])
    assert objectives([scores, None], no_episode=run) == run == (10.0, 1.0)
