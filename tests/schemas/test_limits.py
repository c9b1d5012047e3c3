"""The safety measures of real episodes, and the limits they are checked against."""

import dataclasses
import math
import pickle

import numpy as np
import pytest

from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import (
    MEASURED,
    MEASURES,
    NOT_DAMPED,
    NOT_MEASURED,
    SPEED_TOLERANCE,
    Limits,
    before_lag,
    measures,
    named,
    tally,
)
from gainfarm.schemas.objectives import LAG_CAP, lag, score
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.episode import run_episode
from tests.helpers import crafted_log

# Three times the default stiffness, five times its damping: the top of the search space, where
# the issue found the front's most accurate members chattering.
CHATTERING = PDGains(
    kp=tuple(3 * gain for gain in DEFAULT_GAINS.kp), kd=tuple(5 * gain for gain in DEFAULT_GAINS.kd)
)
PATH = TrajectorySpec(kind="fourier", duration=1.5)


def scored(gains: PDGains, plant: str) -> Scores:
    return score(run_episode(EpisodeSpec(gains=gains, trajectory=PATH, plant=PLANTS[plant])))


@pytest.mark.parametrize("plant", ["ideal", "realistic"])
def test_a_chattering_controller_breaks_the_limits_and_the_default_gains_keep_them(
    plant: str,
) -> None:
    limits = Limits()
    smooth, rough = scored(DEFAULT_GAINS, plant), scored(CHATTERING, plant)
    assert limits.violated(measures([smooth])) == ()
    broken = limits.violated(measures([rough]))
    assert {"torque_step", "chatter"} <= set(broken), (plant, rough)
    # Not by a hair: an order of magnitude between them on each.
    assert rough.chatter > 10 * limits.chatter > 100 * smooth.chatter
    assert rough.torque_step > 3 * limits.torque_step > 10 * smooth.torque_step
    # Switched off, a limit is met whatever the measure.
    lenient = Limits(
        torque_step=None,
        saturated_fraction=None,
        speed=None,
        chatter=None,
        lag=None,
        min_damping=None,
    )
    assert lenient.violated(measures([rough])) == ()


def test_a_candidate_is_measured_by_its_worst_episode() -> None:
    calm = Scores(
        f_acc=0.01, f_t=0.1, max_error=0.02, saturated_fraction=0.0, diverged=False, ticks=9
    )
    wild = calm.model_copy(update={"torque_step": 0.5, "speed": 0.2, "chatter": 0.3})
    wild = wild.model_copy(update={"lag": 0.09})
    assert measures([calm, wild]) == (0.5, 0.0, 0.2, 0.3, 0.09, NOT_DAMPED)  # damping unmeasured
    # An episode that did not run: never feasible.
    assert measures([calm, None]) == (*NOT_MEASURED, NOT_DAMPED)
    assert Limits().violated((*NOT_MEASURED, NOT_DAMPED)) == MEASURED
    limits = Limits(torque_step=0.25, speed=None, min_damping=None)
    assert limits.constraints((0.5, 0.0, 9.0, 0.01, 0.03)) == (1.0, -1.0, -1.0, -0.5, -0.5)
    measured = [(0.5, 0.0, 9.0, 0.01, 0.0), (0.1, 0.5, 0.0, 0.03, 0.09), (0.0,) * 5]
    assert tally(limits, measured) == (
        2,
        {"torque_step": 1, "saturated_fraction": 1, "speed": 0, "chatter": 1, "lag": 1},
    )


@pytest.mark.parametrize(
    "fields", [{"chatter": 0}, {"speed": -1.0}, {"torque_step": "inf"}, {"jerk": 1.0}]
)
def test_a_limit_is_positive_finite_or_null_and_named(fields: dict) -> None:
    with pytest.raises(ValueError, match=next(iter(fields))):
        Limits.model_validate(fields)


def test_the_damping_is_a_lower_bound_checked_only_when_set() -> None:
    calm = Scores(
        f_acc=0.01, f_t=0.1, max_error=0.02, saturated_fraction=0.0, diverged=False, ticks=9
    )
    damped, ringing = (calm.model_copy(update={"damping": d}) for d in (0.05, -0.02))
    assert measures([damped, ringing])[-1] == -0.02  # the least over the episodes
    unbounded = Limits(min_damping=None)
    assert unbounded.count == 5 and unbounded.names == MEASURES
    assert unbounded.violated(measures([ringing])) == ()
    bounded = Limits(min_damping=0.01)
    assert bounded.count == 6 and bounded.names == MEASURED
    assert bounded.constraints(measures([damped]))[-1] == pytest.approx(-0.04)
    assert bounded.violated(measures([damped, ringing])) == ("damping",)
    assert bounded.violated(measures([calm])) == ("damping",)  # not measured: never feasible
    assert bounded.violated((0.0,) * 5) == ()  # a record from before the damping: not judged
    assert tally(bounded, [measures([damped]), measures([ringing])])[1]["damping"] == 1


@pytest.mark.parametrize("bound", [1.5, -2, "nan"])
def test_a_damping_bound_is_a_damping_ratio(bound: object) -> None:
    with pytest.raises(ValueError, match="min_damping"):
        Limits.model_validate({"min_damping": bound})


def test_scores_pickled_before_the_measures_load_within_every_limit() -> None:
    """An old checkpoint's scores: no measure, read as 0, so never a violation."""
    scores = Scores(
        f_acc=0.01, f_t=0.1, max_error=0.02, saturated_fraction=0.0, diverged=False, ticks=9
    )
    state = scores.__getstate__()
    for name in ("torque_step", "speed", "chatter", "lag", "values", "damping"):
        del state["__dict__"][name]
    old = Scores.__new__(Scores)
    old.__setstate__(state)
    assert pickle.loads(pickle.dumps(old)) == scores
    assert Limits(min_damping=None).violated(measures([old])) == ()
    assert old.lag == 0.0


# --- the lag: every joint's tracking, which the flange's position cannot see -----------------


def test_the_lag_is_the_worst_joints_rms_over_the_ticks_run() -> None:
    log = crafted_log(planned=5)  # three ticks run of five: the RMS is over the three
    q = np.zeros((3, 7))
    q[:, 1] = (0.01, -0.02, 0.02)  # A2: RMS √(0.0009 / 3) = 0.01732 rad
    q[:, 6] = (0.03, 0.0, 0.0)  # A7: RMS √(0.0009 / 3) too, behind a moving reference
    q_des = np.zeros((3, 7))
    q_des[:, 6] = (0.0, 0.0, 0.03)  # so A7's errors are 0.03, 0 and −0.03: RMS 0.02449
    crafted = dataclasses.replace(log, q=q, q_des=q_des)
    assert lag(crafted) == pytest.approx(math.sqrt((0.03**2 + 0.03**2) / 3), rel=1e-12)
    assert score(crafted).lag == lag(crafted)
    assert lag(dataclasses.replace(log, q=q * 0)) == 0.0  # on its reference
    wild = dataclasses.replace(log, q=np.full((3, 7), np.nan))
    assert lag(wild) == LAG_CAP  # a wild simulation's is capped, as the wire bounds it


def test_the_default_gains_keep_the_default_limits_on_the_default_job() -> None:
    """The defaults' measures on the default 5 s spiral, the realistic plant, against the new
    defaults: the data sheet's speed, the lag limit and the damping bound among them."""
    job = EpisodeSpec(gains=DEFAULT_GAINS)
    scores = score(run_episode(job))
    limits = Limits()
    assert limits.speed == 1.0 and limits.lag is not None and limits.min_damping is not None
    assert limits.violated(measures([scores])) == (), scores
    # With a margin on each, not by a hair (measured: speed 0.52, lag 6.0 mrad, damping +0.013).
    assert scores.speed < 0.6 * limits.speed
    assert scores.lag < 0.2 * limits.lag
    assert scores.damping is not None and scores.damping > limits.min_damping + 0.05


def test_a_wrist_at_a_hundredth_of_its_gains_breaks_the_lag_limit_alone() -> None:
    """A7 at a hundredth of the default gains: invisible in f_acc (the flange's position), but
    A7 lags its reference by a quarter of a radian, which the lag limit refuses."""
    weak = PDGains(
        kp=(*DEFAULT_GAINS.kp[:-1], DEFAULT_GAINS.kp[-1] / 100),
        kd=(*DEFAULT_GAINS.kd[:-1], DEFAULT_GAINS.kd[-1] / 100),
    )
    default, wrist = (
        score(run_episode(EpisodeSpec(gains=gains))) for gains in (DEFAULT_GAINS, weak)
    )
    assert abs(wrist.f_acc - default.f_acc) < 0.01 * default.f_acc  # f_acc cannot tell them apart
    assert Limits().violated(measures([wrist])) == ("lag",), wrist
    assert wrist.lag > 3 * Limits().lag > 10 * default.lag


def test_the_speed_is_judged_with_its_stated_tolerance() -> None:
    """The data sheet's speed, overshot by a controller following a reference at up to it: 10 %
    over is allowed, more is not, and a tighter limit is tolerated by the same share."""
    assert SPEED_TOLERANCE == 0.1 and Limits().speed == 1.0
    lenient = {"lag": None, "min_damping": None}
    at = {share: (0.0, 0.0, share, 0.0, 0.0) for share in (1.05, 1.099, 1.101)}
    assert Limits(**lenient).violated(at[1.099]) == ()
    assert Limits(**lenient).violated(at[1.101]) == ("speed",)
    assert Limits(**lenient).constraints(at[1.05])[2] == pytest.approx(1.05 / 1.1 - 1)
    assert Limits(speed=0.9, **lenient).violated((0.0, 0.0, 0.98, 0.0, 0.0)) == ()  # 0.99 allowed
    assert Limits(speed=0.9, **lenient).violated((0.0, 0.0, 1.0, 0.0, 0.0)) == ("speed",)


def test_a_record_from_before_the_lag_reads_it_as_zero() -> None:
    """front.json and evaluated.csv name their measures: one from before the lag has none (never
    a violation), one from before the damping neither; a checkpoint's are in their old order."""
    old = {"torque_step": 0.01, "saturated_fraction": 0.0, "speed": 0.5, "chatter": 0.001}
    assert named(old) == (0.01, 0.0, 0.5, 0.001, 0.0)
    assert named(old | {"damping": -0.02}) == (0.01, 0.0, 0.5, 0.001, 0.0, -0.02)
    assert named({}) == ()  # a run from before the limits
    assert before_lag((0.01, 0.0, 0.5, 0.001, -0.02)) == (0.01, 0.0, 0.5, 0.001, 0.0, -0.02)
    assert before_lag((0.01, 0.0, 0.5, 0.001)) == (0.01, 0.0, 0.5, 0.001, 0.0)
    assert Limits().violated(named(old | {"damping": -0.02})) == ()
