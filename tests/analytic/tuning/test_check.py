"""The held-out check's advice: a member is the controller to use only if it holds against the
default gains on the plants the run never saw, in absolute terms."""

from dataclasses import replace

import numpy as np
import pytest

from gainfarm.analytic.tuning.check import Checked, _judged, advice_of, failures
from gainfarm.analytic.tuning.picks import Advice, picks
from gainfarm.analytic.tuning.records import Baseline, FrontMember
from gainfarm.schemas.gains import DEFAULT_GAINS

DEFAULT = Checked(
    name="default gains",
    row=None,
    kp=DEFAULT_GAINS.kp,
    kd=DEFAULT_GAINS.kd,
    nominal_f_acc=2.0e-3,
    nominal_f_t=0.1,
    nominal_failed=False,
    nominal_lag=7.0e-3,
    median_f_acc=8.0e-3,
    worst_f_acc=12.0e-3,
    violations=0,
    diverged=0,
)


def _member(row: int, **changed: object) -> Checked:
    fields = {"nominal_f_acc": 1.5e-3, "nominal_f_t": 0.08, "median_f_acc": 7.0e-3}
    fields.update(changed)
    gains = tuple(float(row + joint) for joint in range(7))
    return replace(DEFAULT, name="candidate", row=row, kp=gains, kd=gains, **fields)


def test_a_member_that_holds_against_the_defaults_has_no_failure() -> None:
    assert failures(_member(1), DEFAULT) == ()
    assert failures(_member(1, worst_f_acc=DEFAULT.worst_f_acc), DEFAULT) == ()  # as bad: holds


@pytest.mark.parametrize(
    ("changed", "says"),
    [
        ({"median_f_acc": 8.5e-3}, "median held-out error 8.50 mm > 8.00"),
        ({"worst_f_acc": 13.0e-3}, "worst held-out error 13.00 mm > 12.00"),
        (
            {"violations": 2, "failed_on": (3, 9)},
            "broke a limit or diverged on 2 held-out plants the default gains keep to",
        ),
        (
            {"diverged": 1, "failed_on": (4,)},
            "broke a limit or diverged on 1 held-out plant the default gains keep to",
        ),
        ({"nominal_f_t": 0.2}, "does not dominate the default gains on the nominal plant"),
        ({"nominal_f_acc": 2.5e-3}, "does not dominate the default gains on the nominal plant"),
        ({"nominal_failed": True}, "failed on the nominal plant"),
        ({"nominal_lag": 0.024}, "a joint lags by 24.0 mrad RMS on the nominal plant > 7.0"),
    ],
)
def test_each_way_a_member_falls_short_is_said(changed: dict, says: str) -> None:
    assert failures(_member(1, **changed), DEFAULT) == (says,)


def test_a_member_less_damped_than_the_defaults_when_the_command_is_late_falls_short() -> None:
    theirs = {"delay": 2, "tracking_at_delay": 0.063}
    default = replace(DEFAULT, margins=theirs)
    ringing = _member(1, margins={"delay": 2, "tracking_at_delay": -0.088})
    assert failures(ringing, default) == ("tracking damping -0.088 2 ticks late < 0.063",)
    damped = _member(1, margins={"delay": 2, "tracking_at_delay": 0.07})
    assert failures(damped, default) == ()
    alike = _member(1, margins={"delay": 2, "tracking_at_delay": 0.0626})  # a thousandth off
    assert failures(alike, default) == ()
    less = _member(1, margins={"delay": 2, "tracking_at_delay": 0.0615})
    assert failures(less, default) == ("tracking damping 0.061 2 ticks late < 0.063",)


def test_the_first_candidate_that_holds_is_recommended_and_the_others_say_why_not() -> None:
    checked = [
        _member(3, worst_f_acc=20e-3),  # the knee's first choice, worse held out
        replace(_member(5), name="knee"),  # holds, but the knee is not a candidate
        DEFAULT,
        _member(1),
        _member(2),
    ]
    judged = _judged(checked)
    assert [item.name for item in judged] == [
        "candidate",
        "knee",
        "default gains",
        "recommended",
        "candidate",
    ]
    assert judged[0].failed == ("worst held-out error 20.00 mm > 12.00",)
    assert judged[3].failed == judged[4].failed == judged[1].failed == ()
    assert _judged([_member(3, diverged=2, failed_on=(1, 2)), DEFAULT])[0].name == "candidate"


def test_a_member_may_break_a_limit_only_where_the_default_gains_break_it_too() -> None:
    default = replace(DEFAULT, violations=1, failed_on=(27,))
    assert failures(_member(1, violations=1, failed_on=(27,)), default) == ()
    assert failures(_member(1, violations=2, failed_on=(5, 27)), default) == (
        "broke a limit or diverged on 1 held-out plant the default gains keep to",
    )


def _front_member(row: int, f_acc: float, f_t: float) -> FrontMember:
    gains = tuple(float(row + joint) for joint in range(7))
    return FrontMember(kp=gains, kd=gains, objectives=(f_acc, f_t))


def test_the_checks_advice_decides_the_recommended_member() -> None:
    front = [_front_member(1, 1e-3, 0.3), _front_member(2, 2e-3, 0.2), _front_member(3, 3e-3, 0.1)]
    baseline = Baseline(gains=DEFAULT_GAINS, objectives=(4e-3, 0.4), diverged=False)
    unchecked = picks(front, baseline)[0]
    assert unchecked.name == "recommended" and unchecked.row == 2  # the knee: it dominates
    advised = picks(front, baseline, Advice(front[2].gains))[0]
    assert (advised.name, advised.row) == ("recommended", 3)
    kept = picks(front, baseline, Advice(None))[0]
    assert kept.name == "closest"  # the defaults are kept: no member is recommended
    gone = picks(front, baseline, Advice(DEFAULT_GAINS))[0]  # advice for gains not on the front
    assert gone.name == "closest"


def test_advice_is_read_from_the_check_record() -> None:
    assert advice_of(None) is None
    assert advice_of({"plants": 3, "controllers": []}) is None  # a check from before the advice
    assert advice_of({"advice": {"row": None}}) == Advice(None)
    gains = {"row": 4, "kp": list(DEFAULT_GAINS.kp), "kd": list(DEFAULT_GAINS.kd)}
    assert advice_of({"advice": gains}) == Advice(DEFAULT_GAINS)


def test_a_member_that_is_the_default_gains_is_no_candidate_to_replace_them() -> None:
    from gainfarm.analytic.tuning.check import _candidates
    from gainfarm.analytic.tuning.search_space import SearchSpace

    space = SearchSpace()  # NSGA-II's first sample, through the decision space and back
    defaults = space.gains(np.log10(np.array(DEFAULT_GAINS.kp + DEFAULT_GAINS.kd)))
    baseline = Baseline(gains=DEFAULT_GAINS, objectives=(2e-3, 0.1), diverged=False)
    them = FrontMember(kp=defaults.kp, kd=defaults.kd, objectives=(2e-3, 0.1))
    other = _front_member(1, 1e-3, 0.3)
    assert (
        _candidates([other, them], baseline, DEFAULT_GAINS) == []
    )  # the closest is them: none is left
    better = _front_member(2, 1.5e-3, 0.09)
    assert _candidates([other, better, them], baseline, DEFAULT_GAINS) == [1]
