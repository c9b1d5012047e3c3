"""Practical measures of tuned fronts, beside their hypervolume, in the units a user reads:
millimetres of error and (N·m)² of torque change.

- The error at a fixed torque smoothness (`smoothness_level`, `error_at`): every front judged at
  one f_t, the least every front of the comparison reaches, by its best error among members at
  least that smooth. The most accurate member is often a chattering one (f_t 10²-10⁴ times a
  smooth one's), so its error measures how far a front reaches into chatter more than how well
  it tracks; at one smoothness the fronts compare on the same footing.
- The recommended controller (`recommended`): the member a user is given (analytic.tuning.picks:
  the knee among the members that dominate the default gains, or the one closest to dominating
  them if none does), its error and its f_t.
- `median_interval`: a median with its 95 % bootstrap confidence interval, as the reports show
  each condition's; `difference`: a comparison's effect in its unit, significant or not.
"""

import math
import warnings
from collections.abc import Sequence

import numpy as np
from scipy import stats

from gainfarm.analytic.experiments.normalisation import Point, is_penalty, non_dominated
from gainfarm.analytic.experiments.statistics import CONFIDENCE, RESAMPLES, Comparison
from gainfarm.analytic.tuning.picks import Pick, picks
from gainfarm.analytic.tuning.records import BASELINE_JSON, RunRecord, read_baseline

F_T_TINY = 1e-12  # (N·m)²: an f_t of 0 on the log scale the interpolation is taken on


def _measured(points: Sequence[Point], penalised: frozenset[Point] | set[Point]) -> list[Point]:
    return [p for p in points if not is_penalty(p, penalised)]


def smoothness_level(
    point_sets: Sequence[Sequence[Point]], penalised: frozenset[Point] | set[Point] = frozenset()
) -> float:
    """The least f_t every front of `point_sets` reaches: the largest of the fronts' smoothest
    measured members' f_t (penalty points left out, fronts without a measured member ignored);
    NaN if no front has one."""
    smoothest = [
        min(p[1] for p in measured)
        for points in point_sets
        if (measured := _measured(points, penalised))
    ]
    return max(smoothest, default=math.nan)


def error_at(
    points: Sequence[Point], level: float, penalised: frozenset[Point] | set[Point] = frozenset()
) -> float:
    """The error (f_acc, m) of the front `points` at torque smoothness `level`: its best error
    among members with f_t ≤ level, interpolated along the front between the two non-dominated
    members around the level (linearly in log f_t: a front spans decades of f_t), so a front
    with no member just at the level is not judged by its neighbour's step. NaN if no measured
    member is that smooth."""
    measured = _measured(points, penalised)
    if not measured:
        return math.nan
    front = sorted(set(non_dominated(measured)), key=lambda p: p[1])  # the smoothest first
    if front[0][1] > level:
        return math.nan
    f_t = np.log(np.maximum([p[1] for p in front], F_T_TINY))
    return float(np.interp(math.log(max(level, F_T_TINY)), f_t, [p[0] for p in front]))


def recommended(record: RunRecord) -> Pick | None:
    """The run's recommended controller (picks' "recommended"), or the member closest to
    dominating the default gains if none does ("closest"), from its baseline.json; without one
    (a run stopped before it scored the defaults), the knee. None if the front is empty."""
    path = record.directory / BASELINE_JSON
    try:
        baseline = read_baseline(path) if path.exists() else None
    except ValueError:
        baseline = None
    chosen = picks(record.front, baseline)
    return chosen[0] if chosen else None


def median(values: Sequence[float]) -> float:
    """The median of `values`, NaNs left out (NaN if none is left)."""
    x = [v for v in values if math.isfinite(v)]
    return float(np.median(x)) if x else math.nan


def median_interval(values: Sequence[float], seed: int = 0) -> tuple[float, float, float]:
    """The median of `values` (NaNs left out) and a 95 % bootstrap confidence interval of it
    (percentile method, seeded); the interval is NaN with fewer than two values."""
    x = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    if not len(x):
        return math.nan, math.nan, math.nan
    median = float(np.median(x))
    if len(x) < 2:
        return median, math.nan, math.nan
    if np.all(x == x[0]):  # nothing to resample
        return median, median, median
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        interval = stats.bootstrap(
            (x,),
            np.median,
            n_resamples=RESAMPLES,
            confidence_level=CONFIDENCE,
            method="percentile",
            rng=np.random.default_rng(seed),
        ).confidence_interval
    return median, float(interval.low), float(interval.high)


def shown(values: Sequence[float], scale: float = 1000.0, digits: int = 2) -> str:
    """A median and its interval as a report's cell: "5.61 [5.50, 5.72]" (× `scale`: mm from m
    by default); "n/a" without values, the median alone without an interval."""
    median, low, high = median_interval(values)
    if not math.isfinite(median):
        return "n/a"
    text = f"{median * scale:.{digits}f}"
    if math.isfinite(low):
        text += f" [{low * scale:.{digits}f}, {high * scale:.{digits}f}]"
    return text


def difference(comparison: Comparison, unit: str = "") -> str:
    """A comparison's effect in its measure's unit, whatever its test says: the difference of
    the medians (a − b) and its 95 % bootstrap interval, "−0.12 mm [−0.30, +0.05]"."""
    c = comparison
    text = f"{c.median_a - c.median_b:+.3g}" + (f" {unit}" if unit else "")
    if math.isfinite(c.ci_low):
        text += f" [{c.ci_low:+.3g}, {c.ci_high:+.3g}]"
    return text
