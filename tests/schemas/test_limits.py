"""The safety measures of real episodes, and the limits they are checked against."""

import pickle

import pytest

from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import (
    MEASURED,
    MEASURES,
    NOT_DAMPED,
    NOT_MEASURED,
    Limits,
    measures,
    tally,
)
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.episode import run_episode

# Three times the default stiffness, five times its damping: the top of the search space, where
# the issue found the front's most accurate members chattering.
CHATTERING = PDGains(
    kp=tuple(3 * gain for gain in DEFAULT_GAINS.kp), kd=tuple(5 * gain for gain in DEFAULT_GAINS.kd)
)
PATH = TrajectorySpec(kind="fourier", duration=1.5)


def scored(gains: PDGains, plant: str) -> Scores:
    return score(run_episode(EpisodeSpec(gains=gains, trajectory=PATH, model=PLANTS[plant])))


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
    lenient = Limits(torque_step=None, saturated_fraction=None, speed=None, chatter=None)
    assert lenient.violated(measures([rough])) == ()


def test_a_candidate_is_measured_by_its_worst_episode() -> None:
    calm = Scores(
        f_acc=0.01, f_t=0.1, max_error=0.02, saturated_fraction=0.0, diverged=False, ticks=9
    )
    wild = calm.model_copy(update={"torque_step": 0.5, "speed": 0.2, "chatter": 0.3})
    assert measures([calm, wild]) == (0.5, 0.0, 0.2, 0.3, NOT_DAMPED)  # damping not measured
    # An episode that did not run: never feasible.
    assert measures([calm, None]) == (*NOT_MEASURED, NOT_DAMPED)
    assert Limits().violated((*NOT_MEASURED, NOT_DAMPED)) == MEASURES
    limits = Limits(torque_step=0.25, speed=None)
    assert limits.constraints((0.5, 0.0, 9.0, 0.01)) == (1.0, -1.0, -1.0, -0.5)
    assert tally(limits, [(0.5, 0.0, 9.0, 0.01), (0.1, 0.5, 0.0, 0.03), (0.0,) * 4]) == (
        2,
        {"torque_step": 1, "saturated_fraction": 1, "speed": 0, "chatter": 1},
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
    unbounded = Limits()
    assert unbounded.count == 4 and unbounded.names == MEASURES
    assert unbounded.violated(measures([ringing])) == ()
    bounded = Limits(min_damping=0.01)
    assert bounded.count == 5 and bounded.names == MEASURED
    assert bounded.constraints(measures([damped]))[-1] == pytest.approx(-0.04)
    assert bounded.violated(measures([damped, ringing])) == ("damping",)
    assert bounded.violated(measures([calm])) == ("damping",)  # not measured: never feasible
    assert bounded.violated((0.0,) * 4) == ()  # a record from before the damping: not judged
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
    for name in ("torque_step", "speed", "chatter", "values", "damping"):
        del state["__dict__"][name]
    old = Scores.__new__(Scores)
    old.__setstate__(state)
    assert pickle.loads(pickle.dumps(old)) == scores
    assert Limits().violated(measures([old])) == ()
