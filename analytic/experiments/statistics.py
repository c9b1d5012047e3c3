"""Two samples compared the way the experiments' findings need: a test, an effect size, a
confidence interval, and a decision in plain words that says when the data cannot decide.

Pure (numpy, scipy), no files: `stats_csv` returns the text of an experiment's stats.csv.

- p_value: Mann-Whitney U, two-sided (exact where scipy can: small samples without ties), for
  independent samples; Wilcoxon signed-rank, two-sided, when the samples are paired (the same
  seed, the same controllers measured twice).
- a12: Vargha and Delaney's A12 = P(a > b) + 0.5 P(a = b), for a value drawn from `a` and one
  from `b`. 0.5: no tendency; 1: every a larger than every b. "Larger" is "better" for a
  hypervolume (higher is better), "worse" for an error (lower is better): `decide` is told which.
- ci_low, ci_high: a 95 % bootstrap confidence interval (scipy.stats.bootstrap, percentile
  method, seeded) of median(a) − median(b); NaN with fewer than two values on a side.
- min_p: the smallest p-value the test can give with these sample sizes whatever the data (the
  exact test's, ties aside): 2 / C(n_a + n_b, n_a) for Mann-Whitney, 2 / 2^n for Wilcoxon.
  Mann-Whitney 3 against 3 can never go below 0.1: such a comparison cannot decide at 0.05.
- p_holm: p_value after Holm's adjustment over the family of comparisons it belongs to (the
  experiment's report names the family); a trailing column of stats.csv only in an experiment
  that adjusts (StatsRow.p_holm), so that every other stats.csv keeps STATS_COLUMNS exactly.
"""

import csv
import io
import math
import warnings
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np
from scipy import stats

K = TypeVar("K", bound=Hashable)

ALPHA = 0.05
CONFIDENCE = 0.95
RESAMPLES = 9999
STATS_COLUMNS = (
    "experiment",
    "comparison",
    "metric",
    "median_a",
    "median_b",
    "p_value",
    "a12",
    "ci_low",
    "ci_high",
    "n_a",
    "n_b",
)


@dataclass(frozen=True)
class Comparison:
    """Sample a against sample b (see the module's docstring for each number)."""

    median_a: float
    median_b: float
    p_value: float
    a12: float
    ci_low: float
    ci_high: float
    n_a: int
    n_b: int
    paired: bool
    min_p: float

    @property
    def test(self) -> str:
        return "Wilcoxon signed-rank" if self.paired else "Mann-Whitney U"


def a12(a: Sequence[float], b: Sequence[float]) -> float:
    """Vargha-Delaney A12: P(a > b) + 0.5 P(a = b); NaN if a sample is empty."""
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if not len(x) or not len(y):
        return math.nan
    greater = (x[:, None] > y[None, :]).sum()
    equal = (x[:, None] == y[None, :]).sum()
    return float((greater + 0.5 * equal) / (len(x) * len(y)))


def min_p_value(n_a: int, n_b: int, paired: bool) -> float:
    """The smallest two-sided p-value the exact test can reach with these sample sizes."""
    if paired:
        return 1.0 if n_a < 1 else min(1.0, 2.0 / 2.0**n_a)
    if n_a < 1 or n_b < 1:
        return 1.0
    return min(1.0, 2.0 / math.comb(n_a + n_b, n_a))


def _p_value(x: np.ndarray, y: np.ndarray, paired: bool) -> float:
    if not len(x) or not len(y):
        return math.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        if paired:
            if np.all(x == y):
                return 1.0
            return float(stats.wilcoxon(x, y, alternative="two-sided").pvalue)
        if np.all(np.concatenate([x, y]) == x[0]):
            return 1.0
        return float(stats.mannwhitneyu(x, y, alternative="two-sided", method="auto").pvalue)


def _median_difference_ci(
    x: np.ndarray, y: np.ndarray, paired: bool, seed: int
) -> tuple[float, float]:
    if len(x) < 2 or len(y) < 2:
        return math.nan, math.nan

    def difference(a: np.ndarray, b: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.median(a, axis=axis) - np.median(b, axis=axis)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        interval = stats.bootstrap(
            (x, y),
            difference,
            paired=paired,
            vectorized=True,
            n_resamples=RESAMPLES,
            confidence_level=CONFIDENCE,
            method="percentile",
            rng=np.random.default_rng(seed),
        ).confidence_interval
    return float(interval.low), float(interval.high)


def compare(
    a: Sequence[float], b: Sequence[float], paired: bool = False, seed: int = 0
) -> Comparison:
    """Sample `a` against sample `b`; `paired`: a[i] and b[i] belong together (equal lengths)."""
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if paired and len(x) != len(y):
        raise ValueError(f"paired samples need equal lengths, got {len(x)} and {len(y)}")
    low, high = _median_difference_ci(x, y, paired, seed)
    return Comparison(
        median_a=float(np.median(x)) if len(x) else math.nan,
        median_b=float(np.median(y)) if len(y) else math.nan,
        p_value=_p_value(x, y, paired),
        a12=a12(x, y),
        ci_low=low,
        ci_high=high,
        n_a=len(x),
        n_b=len(y),
        paired=paired,
        min_p=min_p_value(len(x), len(y), paired),
    )


def decidable(comparison: Comparison, alpha: float = ALPHA) -> bool:
    """Whether these sample sizes can ever give p < alpha."""
    return comparison.min_p < alpha


def significant(comparison: Comparison, alpha: float = ALPHA) -> bool:
    return decidable(comparison, alpha) and comparison.p_value < alpha


def better(
    comparison: Comparison, higher_is_better: bool = True, alpha: float = ALPHA
) -> str | None:
    """Which of a and b ("a", "b") is significantly better; None when the test cannot decide."""
    if not significant(comparison, alpha):
        return None
    a_larger = comparison.a12 > 0.5
    return "a" if a_larger == higher_is_better else "b"


def decide(
    comparison: Comparison,
    name_a: str = "a",
    name_b: str = "b",
    higher_is_better: bool = True,
    alpha: float = ALPHA,
) -> str:
    """The comparison's decision in plain words: which is better, or why it cannot be decided."""
    c = comparison
    numbers = f"{c.test} p = {c.p_value:.3g}, A12 = {c.a12:.2f}"
    if not decidable(c, alpha):
        sizes = f"{c.n_a} pairs" if c.paired else f"{c.n_a} against {c.n_b} repetitions"
        return (
            f"cannot decide between {name_a} and {name_b}: with {sizes} the smallest p-value "
            f"{c.test} can reach is {c.min_p:.3g}, not below {alpha:g}; more repetitions are "
            "needed"
        )
    if not c.p_value < alpha:
        return f"cannot decide between {name_a} and {name_b}: no significant difference ({numbers})"
    winner, loser = (
        (name_a, name_b) if better(c, higher_is_better, alpha) == "a" else (name_b, name_a)
    )
    interval = (
        f"; median difference {c.median_a - c.median_b:+.4g}, 95 % CI "
        f"[{c.ci_low:+.4g}, {c.ci_high:+.4g}]"
        if math.isfinite(c.ci_low)
        else ""
    )
    return f"{winner} is better than {loser} ({numbers}{interval})"


@dataclass(frozen=True)
class StatsRow:
    """One line of stats.csv: which experiment, which comparison ("a vs b"), which metric."""

    experiment: str
    comparison: str
    metric: str
    result: Comparison
    p_holm: float | None = None  # None: not adjusted (see the module's docstring)


def stats_csv(rows: Sequence[StatsRow]) -> bytes:
    """The text of stats.csv: STATS_COLUMNS, one line per comparison, and p_holm after them
    if any row has one (empty in a row that has none)."""
    adjusted = any(row.p_holm is not None for row in rows)
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(STATS_COLUMNS + (("p_holm",) if adjusted else ()))
    for row in rows:
        r = row.result
        holm_column = ["" if row.p_holm is None else row.p_holm] if adjusted else []
        writer.writerow(
            [
                row.experiment,
                row.comparison,
                row.metric,
                r.median_a,
                r.median_b,
                r.p_value,
                r.a12,
                r.ci_low,
                r.ci_high,
                r.n_a,
                r.n_b,
                *holm_column,
            ]
        )
    return buffer.getvalue().encode()


def least_reps(family: int, paired: Sequence[bool] = (False,), alpha: float = ALPHA) -> int:
    """The fewest repetitions (n against n, or n pairs) with which any claim of a Holm family of
    `family` claims can reach an adjusted p < alpha whatever the others' p-values: the smallest
    raw p of each kind of test in `paired` (Wilcoxon signed-rank if True, else Mann-Whitney U)
    times the family's size."""
    n = 1
    while family * max(min_p_value(n, n, each) for each in paired) >= alpha:
        n += 1
    return n


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of a family of p-values (NaN ones stay NaN, not counted)."""
    tested = [index for index, p in enumerate(p_values) if math.isfinite(p)]
    order = sorted(tested, key=lambda index: p_values[index])
    adjusted = [math.nan] * len(p_values)
    running = 0.0
    for rank, index in enumerate(order):
        running = max(running, min(1.0, (len(order) - rank) * p_values[index]))
        adjusted[index] = running
    return adjusted


def holm_adjusted(results: Mapping[K, Comparison]) -> dict[K, Comparison]:
    """The family `results` with Holm-adjusted p-values, and with the smallest adjusted p-value
    each can reach (Holm multiplies the family's smallest p by its size, so a sample size that
    could decide one test alone may decide none of many): `decidable`, `better` and `decide`
    then judge each claim as one of the family."""
    adjusted = holm([r.p_value for r in results.values()])
    tested = [r.min_p for r in results.values() if math.isfinite(r.p_value)]
    floor = len(tested) * min(tested, default=0.0)
    return {
        key: replace(r, p_value=p, min_p=min(1.0, max(r.min_p, floor)))
        for (key, r), p in zip(results.items(), adjusted, strict=True)
    }
