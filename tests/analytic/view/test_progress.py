"""The words of the progress lines; the lines themselves, on a terminal and off one, are tested
through `analytic start` in tests/analytic/commands/test_cli.py."""

import math

import pytest

from gainfarm.analytic.tuning.run import RunProgress
from gainfarm.analytic.view.progress import NONE_YET, fit, generation_line, live_line

BEFORE_ANY = RunProgress(
    generation=0, evaluations=3, hypervolume=math.nan, best_f_acc=math.nan, elapsed=1.5
)
LATE = RunProgress(
    generation=41, evaluations=12_345, hypervolume=0.81234, best_f_acc=0.00592, elapsed=1074.2
)
ENDED = RunProgress(
    generation=3, evaluations=90, hypervolume=0.6123, best_f_acc=0.0143, elapsed=7.4, ended=True
)


def test_no_figure_is_shown_before_a_generation_has_given_one() -> None:
    line = live_line(BEFORE_ANY, 1, None, 78)
    assert line == f"gen 1 · 3 evals · 2.0/s · HV {NONE_YET} · best {NONE_YET} · 1 worker"
    assert "nan" not in line


def test_the_line_says_the_generation_under_way_and_the_workers_now() -> None:
    assert live_line(LATE, 2, None, 78) == (
        "gen 42 · 12,345 evals · 11.5/s · HV 0.8123 · best 5.92 mm · 2 workers"
    )
    assert live_line(ENDED, 1, None, 78).startswith("gen 3 · 90 evals")


@pytest.mark.parametrize(
    ("workers", "waiting", "says"),
    [
        (0, None, "waiting for workers"),
        (None, "the broker does not answer", "broker lost, waiting"),
        (3, "the broker is gone", "broker lost, waiting"),
    ],
)
def test_what_holds_the_run_up_is_said_first(
    workers: int | None, waiting: str | None, says: str
) -> None:
    for step in (None, BEFORE_ANY, LATE):
        line = live_line(step, workers, waiting, 78)
        assert line.startswith(says), line
        assert "worker" not in line.removeprefix(says)  # no stale count beside it


def test_before_the_first_result_the_line_says_it_is_starting() -> None:
    assert live_line(None, 1, None, 78) == "starting · 1 worker"


@pytest.mark.parametrize("width", [78, 60, 40, 25, 10])
@pytest.mark.parametrize("waiting", [None, "the broker is gone"])
def test_every_line_fits_the_width_it_is_given(width: int, waiting: str | None) -> None:
    for step in (None, BEFORE_ANY, LATE, ENDED):
        for workers in (None, 0, 1, 256):
            assert len(live_line(step, workers, waiting, width)) <= width


def test_fit_drops_the_least_important_parts_first() -> None:
    parts = [(3, "aaaa"), (1, "bbbb"), (2, "cccc")]
    assert fit(parts, 80) == "aaaa · bbbb · cccc"
    assert fit(parts, 12) == "aaaa · cccc"
    assert fit(parts, 5) == "aaaa"
    assert fit(parts, 3) == "aa…"


def test_a_generation_s_plain_line() -> None:
    assert generation_line(ENDED, 2) == (
        "generation 3: 90 evaluations in 7.4 s (12.2/s), hypervolume 0.6123, "
        "best error 14.30 mm, 2 workers"
    )
    assert generation_line(ENDED, None).endswith("workers: ?")


def test_a_budget_gives_the_time_left_at_the_runs_pace_and_convergence_none() -> None:
    budgeted = RunProgress(
        generation=3, evaluations=90, hypervolume=0.6, best_f_acc=0.01, elapsed=9.0, ended=True,
        budget=600,
    )  # fmt: skip
    # 510 evaluations left at 10 per second.
    assert generation_line(budgeted, 2).endswith(
        "2 workers; about 51 s left of its 600 evaluations at this pace"
    )
    assert "~51 s left" in live_line(budgeted, 2, None, 120)
    later = RunProgress(**{**budgeted.__dict__, "evaluations": 100, "elapsed": 100.0})
    assert "~8 min left" in live_line(later, 2, None, 120)  # 500 at 1/s: 8 min 20 s
    assert "left" not in live_line(ENDED, 2, None, 120)  # no budget, no estimate of convergence
    spent = RunProgress(**{**budgeted.__dict__, "evaluations": 600, "elapsed": 60.0})
    # The last generation: nothing is left, so nothing is guessed ("about 0 s left").
    assert generation_line(spent, 2).endswith("2 workers")
    assert "left" not in live_line(spent, 2, None, 120)
    assert "left" not in generation_line(ENDED, 2)


def test_a_converging_run_s_time_left_is_its_fitted_end_at_its_pace_and_says_so() -> None:
    converging = RunProgress(
        generation=3, evaluations=90, hypervolume=0.6, best_f_acc=0.01, elapsed=9.0, ended=True,
        expected=300,
    )  # fmt: skip
    assert generation_line(converging, 2).endswith(
        "2 workers; about 21 s left if it converges at about 300 evaluations, as a fit of its "
        "hypervolume's course says (a rough guess)"
    )
    assert "~21 s left?" in live_line(converging, 2, None, 120)  # a guess, and marked one
