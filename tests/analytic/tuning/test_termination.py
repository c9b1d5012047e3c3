"""When a run stops, as a pure function of its hypervolumes and evaluations."""

import math

from gainfarm.analytic.tuning.termination import Termination, expected_generations


def test_a_fixed_number_of_generations_or_evaluations() -> None:
    assert Termination(generations=3).reason([0.1, 0.2], 60) is None
    assert Termination(generations=3).reason([0.1, 0.2, 0.3], 90) == "3 generations"
    assert Termination(generations=1).reason([0.1], 30) == "1 generation"
    assert Termination(evaluations=1).reason([0.1], 1) == "1 evaluation"
    assert Termination(evaluations=100).reason([0.1, 0.2, 0.3], 90) is None
    assert Termination(evaluations=100).reason([0.1] * 4, 120) == "120 evaluations"


def test_convergence_needs_a_whole_window_of_small_gains() -> None:
    converge = Termination(tolerance=0.01, window=2)
    assert converge.reason([0.5, 0.5], 60) is None  # not yet a window to compare with
    assert converge.reason([0.5, 0.6, 0.7], 90) is None  # still growing by 40 %
    reason = converge.reason([0.5, 0.6, 0.7, 0.7, 0.705], 150)
    assert reason is not None and reason.startswith("converged after 150 evaluations")


def test_a_zero_hypervolume_is_never_convergence() -> None:
    assert Termination(window=1).reason([0.0, 0.0, 0.0], 90) is None


def test_the_rule_reads_as_set() -> None:
    assert Termination().rule == "hypervolume gain below 0.25% over 10 generations"
    reason = Termination(tolerance=0.0025, window=1).reason([1.0, 1.001], 60)
    assert reason == (
        "converged after 60 evaluations (hypervolume gain below 0.25% over 1 generations)"
    )


def test_the_convergence_is_expected_where_the_fitted_course_meets_the_rule() -> None:
    rule = Termination()
    # A course that slows as an exponential does: h = 0.8 − 0.3·exp(−g/6). The rule (0.25 %
    # over 10 generations) stops it at the first g > 10 with 0.3·e^(−g/6)·(e^(10/6) − 1)
    # ≤ 0.0025·h(g − 10): generation 37.
    course = [0.8 - 0.3 * math.exp(-g / 6) for g in range(1, 60)]
    stop = next(g for g in range(11, 60) if rule.reason(course[:g], 0) is not None)
    assert stop == 39
    for now in (5, 12, 20, 30):
        assert expected_generations(rule, course[:now]) == stop
    assert expected_generations(rule, course[:stop]) == stop  # it stops now
    assert expected_generations(rule, course[:4]) is None  # too few to fit
    assert expected_generations(Termination(generations=40), course[:20]) is None  # a budget
    assert expected_generations(rule, [0.0] * 8) is None  # nothing found yet
    # A flat course converges as soon as the rule can see a whole window of it.
    assert expected_generations(rule, [0.5] * 6) == 11
