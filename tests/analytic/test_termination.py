"""When a run stops, as a pure function of its hypervolumes and evaluations."""

from gainfarm.analytic.tuning.termination import Termination


def test_a_fixed_number_of_generations_or_evaluations() -> None:
    assert Termination(generations=3).reason([0.1, 0.2], 60) is None
    assert Termination(generations=3).reason([0.1, 0.2, 0.3], 90) == "3 generations"
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
