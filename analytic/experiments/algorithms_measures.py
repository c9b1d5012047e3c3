"""What the algorithms experiment measures of each run (analytic.experiments.algorithms): its
conditions, the hypervolume of a run's first evaluations, where the convergence rule would have
stopped it, the evaluations it needs to reach the target, and the comparisons with the reference
condition.
"""

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.normalisation import (
    Normalisation,
    Point,
    front_points,
    is_penalty,
    non_dominated,
)
from gainfarm.analytic.experiments.report import median_attainment
from gainfarm.analytic.tuning import defaults
from gainfarm.analytic.tuning.records import HistoryRow, RunRecord
from gainfarm.analytic.tuning.termination import Termination

FINAL = "final"  # the budget's own comparison, beside the fixed budgets'
# What f_t the runs minimise: the paper's Eq. 1 (raw squared torque changes, summed over joints,
# which A1 and A2 dominate) or each joint's change weighed by its torque limit
# (schemas.objectives.f_t_joint).
TORQUE_MEASURES = defaults.TORQUE_MEASURES
TORQUE_TEXT = {
    "raw": "f_t (the paper's Eq. 1: raw squared torque changes summed over the joints)",
    "per-joint": "f_t_joint (each joint's squared torque change weighed by its torque limit, "
    "schemas.objectives)",
}
# The algorithms run in a steady state, told each result as it returns: TPE is sequential by
# design (each trial sampled from every one told), so a generation of 30 asked at once under the
# constant liar wastes it. The others run generationally, as the paper's NSGA-II does.
STEADY = ("tpe",)
TARGET = 0.99  # of the reference condition's median final hypervolume
TARGET_TEXT = "99 %"
SPACE = "all runs"  # the one problem: normalisation.json's key


@dataclass(frozen=True)
class Condition:
    """One optimiser told one kind of objectives."""

    algorithm: str
    scaling: str

    @property
    def name(self) -> str:
        """As its runs' directories and stats.csv name it: 'nsga2-raw'."""
        return f"{self.algorithm}-{self.scaling}"

    @property
    def asynchronous(self) -> bool:
        """Whether its runs are steady-state (STEADY)."""
        return self.algorithm in STEADY


@dataclass(frozen=True)
class RunMeasure:
    """One run's numbers in the experiment's normalisation (see the module's docstring)."""

    evaluations: int
    hypervolume: float
    best_f_acc: float  # m
    curve: list[float]  # hypervolume of the first k evaluations, at each checkpoint
    stopped_by_rule_at: int | None  # None: the rule would not have stopped it within the budget
    hv_at_rule_stop: float | None


@dataclass(frozen=True)
class ConditionSummary:
    """A condition of the experiment over its repetitions, as its table shows it."""

    algorithm: str
    scaling: str
    runs: int
    median_hypervolume: float
    hypervolume_quartiles: tuple[float, float]
    median_best_f_acc: float  # m
    median_evaluations_to_target: float  # inf when fewer than half of the runs reach it
    reached_target: int  # runs that reach it
    median_at_budgets: tuple[float, ...] = ()  # median hypervolume at each fixed budget


# --- measures: pure functions of a run's records -----------------------------------------------


def measured(points: Sequence[Point], penalised: frozenset[Point] | set[Point]) -> list[Point]:
    """`points` without penalties: what a controller really did."""
    return [point for point in points if not is_penalty(point, penalised)]


def feasible(record: RunRecord) -> list[bool]:
    """Whether each evaluated point of the run kept its safety limits (all, in a run from
    before them): only those can be on a front."""
    if len(record.measured) != len(record.evaluated):
        return [True] * len(record.evaluated)
    return [not record.config.limits.violated(values) for values in record.measured]


def first_front(
    record: RunRecord, k: int, penalised: frozenset[Point] | set[Point] = frozenset()
) -> list[Point]:
    """The feasible, measured front of the run's first `k` evaluations."""
    kept = feasible(record)[:k]
    points = [p for p, ok in zip(record.evaluated[:k], kept, strict=True) if ok]
    return non_dominated(measured(points, penalised)) if points else []


def checkpoints(pop: int, budget: int) -> list[int]:
    """Where a run's progress is measured: after every `pop` evaluations (a generation), and at
    the budget."""
    return [*range(pop, budget, pop), budget]


def hypervolume_curve(
    evaluated: Sequence[Point],
    at: Sequence[int],
    normalisation: Normalisation,
    penalised: frozenset[Point] | set[Point] = frozenset(),
    kept: Sequence[bool] | None = None,
) -> list[float]:
    """The hypervolume of the non-dominated set of the first k points of `evaluated`, for each k
    of `at` (ascending), kept as a running front so that each point is sorted in once; `kept`:
    which points count (the feasible ones), all if None."""
    front: list[Point] = []
    done = 0
    curve = []
    for k in at:
        new = [
            p
            for index, p in enumerate(evaluated[done:k], start=done)
            if kept is None or kept[index]
        ]
        front = non_dominated(front + measured(new, penalised))
        done = max(done, k)
        curve.append(normalisation.hypervolume(front))
    return curve


def rule_stop(history: Sequence[HistoryRow], rule: Termination) -> int | None:
    """The evaluations after which `rule` would have stopped the run, judging each generation's
    hypervolume as the run itself does; None if it would have gone on past its history."""
    hypervolumes = [row.hypervolume for row in history]
    for generation, row in enumerate(history, start=1):
        if rule.reason(hypervolumes[:generation], row.evaluations) is not None:
            return row.evaluations
    return None


def evaluations_to(curve: Sequence[float], at: Sequence[int], target: float) -> int | None:
    """The first checkpoint whose hypervolume reaches `target`; None if none does."""
    return next((k for k, value in zip(at, curve, strict=True) if value >= target), None)


def measure(
    record: RunRecord,
    normalisation: Normalisation,
    at: Sequence[int],
    rule: Termination,
    penalised: frozenset[Point] | set[Point] = frozenset(),
) -> RunMeasure:
    front = measured(front_points(record), penalised)
    stop = rule_stop(record.history, rule)
    kept = feasible(record)
    return RunMeasure(
        evaluations=record.evaluations,
        hypervolume=normalisation.hypervolume(front),
        best_f_acc=min((f_acc for f_acc, _ in front), default=math.nan),
        curve=hypervolume_curve(record.evaluated, at, normalisation, penalised, kept),
        stopped_by_rule_at=stop,
        hv_at_rule_stop=(
            None
            if stop is None
            else hypervolume_curve(record.evaluated, [stop], normalisation, penalised, kept)[0]
        ),
    )


def attainment_difference(
    a: Sequence[Sequence[Point]], b: Sequence[Sequence[Point]], normalisation: Normalisation
) -> tuple[float, float]:
    """Where the median runs of two conditions differ (`a`, `b`: one front per repetition): the
    share of the experiment's box the median attainment surface of `a` dominates and that of `b`
    does not, and the other way round. Two numbers, not one: fronts that
    cross each win a region, which a difference of hypervolumes would net out."""
    surface_a, surface_b = median_attainment(a), median_attainment(b)
    both = normalisation.hypervolume([*surface_a, *surface_b])
    return both - normalisation.hypervolume(surface_b), both - normalisation.hypervolume(surface_a)


def summary(
    condition: Condition,
    runs: Sequence[RunMeasure],
    to_target: Sequence[int | None],
    at_budgets: Sequence[Sequence[float]] = (),
) -> ConditionSummary:
    """`condition`'s runs as the report's table shows them (`at_budgets`: each fixed budget's
    hypervolumes, a value per run); a run that never reaches the target counts as needing more
    than any budget."""
    hypervolumes = [run.hypervolume for run in runs]
    low, high = np.percentile(hypervolumes, [25, 75])
    return ConditionSummary(
        algorithm=condition.algorithm,
        scaling=condition.scaling,
        runs=len(runs),
        median_hypervolume=statistics.median(hypervolumes),
        hypervolume_quartiles=(float(low), float(high)),
        median_best_f_acc=float(np.median([run.best_f_acc for run in runs])),
        median_evaluations_to_target=statistics.median(
            math.inf if k is None else k for k in to_target
        ),
        reached_target=sum(k is not None for k in to_target),
        median_at_budgets=tuple(statistics.median(values) for values in at_budgets),
    )


def check_rule(runs: Sequence[RunMeasure]) -> stats.Comparison | None:
    """The hypervolume at the full budget against that at the convergence rule's stop, paired
    by run, over the runs the rule would have stopped within the budget (None if none)."""
    pairs = [(r.hypervolume, r.hv_at_rule_stop) for r in runs if r.hv_at_rule_stop is not None]
    if not pairs:
        return None
    return stats.compare([full for full, _ in pairs], [stop for _, stop in pairs], paired=True)


def against_reference(
    values: Sequence[float], reference: Sequence[float], same_algorithm: bool
) -> stats.Comparison:
    """A condition against the reference. Paired only for the same algorithm told other
    objectives: the same seed then starts it from the very same initial population with the
    very same operators (the scaling changes only what the optimiser is told of each point),
    so repetition r of each is a matched pair. Across algorithms a seed shares at most the
    first population (pymoo's samplers and "random" draw it alike from the seed, tpe does not)
    and nothing after it, so their repetitions are taken as independent: Mann-Whitney, which
    is conservative should they in fact be positively correlated."""
    return stats.compare(values, reference, paired=same_algorithm)


def scores_in(
    points: Sequence[Point], normalisation: Normalisation, penalised: frozenset[Point] | set[Point]
) -> tuple[float, float]:
    """A baseline's hypervolume and best f_acc (m; NaN if it never finished an episode)."""
    kept = measured(points, penalised)
    return normalisation.hypervolume(kept), min((p[0] for p in kept), default=math.nan)
