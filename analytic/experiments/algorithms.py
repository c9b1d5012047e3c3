"""The optimiser comparison the paper left open: which algorithm, told which objectives, finds
the better front on one budget of evaluations, and how soon; what the classical per-joint rule
reaches with no genetic algorithm at all; and whether the run-level convergence rule stops a run
while it still gains.

For each algorithm (analytic.evolution.ALGORITHMS) and objective scaling (OBJECTIVE_SCALINGS),
`reps` tuning runs (seed = rep; Experiment.tune, so kept, resumed or started) on the base spiral,
each stopped at the same budget (the base configuration's evaluations: at the first generation
at or past it, or exactly in a steady state); TPE's runs are steady-state (STEADY: told each
result as it returns), the others generational. The runs minimise f_acc and the torque measure
chosen (TORQUE_MEASURES: the paper's f_t, or f_t_joint, each joint weighed by its limit). And the
classical rule's controllers (analytic.classical) with the default gains, evaluated once on the
same spiral: a no-GA baseline, one deterministic set, so reported, not tested.

Every number is taken in one normalisation of the experiment (base.Normalisation), from
every run's front, penalty points left out (the baselines are measured in it, not part of it):

- hypervolume: of the run's front (front.json, RunRecord.front), the non-dominated set of every
  feasible point it evaluated, as validation by replication left them (evaluated.csv carries the
  same corrections, but a run from before it did not).
- hypervolume after b evaluations, for each fixed budget b (FIXED_BUDGETS) below the budget: of
  the feasible front of the run's first b evaluations (evaluated.csv: the one record of their
  order). A method that gets there sooner is better on a farm whose time is the cost, even if
  all end alike.
- best f_acc: the front's smallest mean error, in mm.
- evaluations to 99 %: the first checkpoint (every `pop` evaluations, and the budget) at which
  the feasible front of the run's first evaluations reaches 99 % of the reference condition's
  median final hypervolume.
- attainment differences: for each condition against the reference, at each budget, the share of
  the box the median attainment surface of one dominates and the other's does not, each way.
- the convergence rule's stop: where the convergence rule of the base configuration (tolerance
  and window: analytic.termination, by default Termination()'s) would have stopped the run, on
  its own per-generation hypervolumes (history.csv), and the experiment's hypervolume of its first
  evaluations up to there.

Each condition is compared with the first (the reference: the first algorithm told the first
scaling, nsga2 raw by default) on hypervolume at every budget (one Holm family) and on best
f_acc (another); and, on the first algorithm's runs, the hypervolume at the rule's stop against
the hypervolume at the full budget, paired by run. Written: results.csv (a row per run),
stats.csv (with p_holm), normalisation.json, algorithms.png and report.md.
"""

import functools
import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.classical import classical_baseline
from gainfarm.analytic.experiments.normalisation import (
    Normalisation,
    Point,
    front_points,
    is_penalty,
    non_dominated,
)
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option, numbers
from gainfarm.analytic.experiments.report import (
    attainment_panel,
    experiment_setup,
    markdown_table,
    median_attainment,
    write_experiment_report,
)
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.experiments.statistics import holm_adjusted
from gainfarm.analytic.tuning import defaults
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import ALGORITHMS, OBJECTIVE_SCALINGS, optimiser
from gainfarm.analytic.tuning.records import HistoryRow, RunRecord
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.analytic.tuning.termination import Termination
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.analytic.view.reports import ALGORITHM_NAMES
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains

NAME = "algorithms"
FINAL = "final"  # the budget's own comparison, beside the fixed budgets'
DEFAULT_BUDGET = 600  # evaluations per run: 20 generations of the default population of 30
# Where else each run's hypervolume is compared: how fast a method gets there matters as much as
# where it ends (random search ends close to NSGA-II on the default problem).
FIXED_BUDGETS = (100, 300)
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
FIGURE = "algorithms.png"
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


# --- checks, before any run ------------------------------------------------------------------


def check_names(names: Sequence[str], allowed: Sequence[str], what: str) -> None:
    """ValueError, in one line, naming the first of `names` not in `allowed` or given twice."""
    seen: set[str] = set()
    for name in names:
        if name not in allowed:
            raise ValueError(f"unknown {what} {name!r}: one of {', '.join(allowed)}")
        if name in seen:
            raise ValueError(f"{what} {name!r} given twice")
        seen.add(name)


def check_runnable(algorithms: Sequence[str], pop: int) -> None:
    """Set every algorithm up once: one this installation cannot run (agemoea2 without numba,
    tpe without optuna) stops the experiment before the others' runs, not hours into it."""
    for algorithm in algorithms:
        optimiser(algorithm, pop, 0, SearchSpace())


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


# --- the experiment ----------------------------------------------------------------------------


def baseline_points(
    experiment: Experiment, base: RunConfig
) -> tuple[list[PDGains], list[Point], Point]:
    """The classical rule's controllers for the base plant, and their points and the default
    gains' on the base trajectory, simulated once (one cross-evaluation, "baselines")."""
    classical = classical_baseline(base.model)
    points = experiment.evaluate_gains(
        "baselines", [*classical.gains, DEFAULT_GAINS], base.trajectories[0], base
    )
    return classical.gains, points[:-1], points[-1]


def run(
    experiment: Experiment,
    base: RunConfig,
    reps: int = 5,
    algorithms: Sequence[str] = ALGORITHMS,
    scalings: Sequence[str] | None = None,
    budgets: Sequence[int] = FIXED_BUDGETS,
    torque_measure: str = "raw",
) -> None:
    """Tune with each algorithm told each scaling (default: the base's), `reps` runs each on
    `base.evaluations`, minimising f_acc and `torque_measure`'s f_t; evaluate the classical
    rule; compare at the budget and at each of `budgets` below it, draw and report."""
    budget = base.evaluations
    if budget is None:
        raise ValueError("the algorithms experiment compares on one budget: give base.evaluations")
    if torque_measure not in TORQUE_MEASURES:
        raise ValueError(
            f"unknown torque measure {torque_measure!r}: one of {', '.join(TORQUE_MEASURES)}"
        )
    scalings = tuple(scalings or (base.objective_scaling,))
    check_names(algorithms, ALGORITHMS, "algorithm")
    check_names(scalings, OBJECTIVE_SCALINGS, "objective scaling")
    check_runnable(algorithms, base.pop)
    base = base.model_copy(update={"objectives": ("f_acc", TORQUE_MEASURES[torque_measure])})
    fixed = sorted({b for b in budgets if 0 < b < budget})
    conditions = [Condition(a, s) for a in algorithms for s in scalings]
    names = {
        (condition, rep): f"{condition.name}-rep{rep}"
        for condition in conditions
        for rep in range(reps)
    }
    tuned = experiment.tune_many(
        {
            name: base.model_copy(
                update={
                    "algorithm": condition.algorithm,
                    "objective_scaling": condition.scaling,
                    "asynchronous": condition.asynchronous,
                    "seed": rep,
                }
            )
            for (condition, rep), name in names.items()
        }
    )
    records = {key: tuned[name] for key, name in names.items()}
    classical_gains, classical, default = baseline_points(experiment, base)
    penalised = experiment.penalised
    # The tuned runs alone set the experiment's space: a stiff classical controller, a little more
    # accurate than any run at a hundred times the torque steps, would stretch it so far that
    # the differences between the optimisers vanish in it. The baselines are measured in it.
    normalisation = experiment.normalisation([front_points(record) for record in records.values()])
    experiment.write_normalisation({SPACE: normalisation})
    generations = checkpoints(base.pop, budget)
    at = sorted({*generations, *fixed})
    # The rule a run of this configuration stops by when it has no budget.
    rule = Termination(tolerance=base.tolerance, window=base.window)
    runs = {
        key: measure(record, normalisation, at, rule, penalised) for key, record in records.items()
    }
    reference = conditions[0]
    target = TARGET * statistics.median(runs[(reference, r)].hypervolume for r in range(reps))
    to_target = {
        key: evaluations_to([run.curve[at.index(k)] for k in generations], generations, target)
        for key, run in runs.items()
    }

    def of(condition: Condition) -> list[RunMeasure]:
        return [runs[(condition, rep)] for rep in range(reps)]

    def at_budget(condition: Condition, b: int) -> list[float]:
        return [r.curve[at.index(b)] for r in of(condition)]

    experiment.write_results(
        [
            {
                "algorithm": condition.algorithm,
                "scaling": condition.scaling,
                "rep": rep,
                "seed": rep,
                "evaluations": run.evaluations,
                "hypervolume": run.hypervolume,
                **{f"hv_at_{b}": run.curve[at.index(b)] for b in fixed},
                "best_f_acc_mm": run.best_f_acc * 1000,
                "evaluations_to_99": to_target[(condition, rep)],
                "stopped_by_rule_at": run.stopped_by_rule_at,
                "hv_at_rule_stop": run.hv_at_rule_stop,
            }
            for (condition, rep), run in runs.items()
        ]
    )

    others = conditions[1:]

    def against(values: Callable[[Condition], list[float]], c: Condition) -> stats.Comparison:
        return against_reference(values(c), values(reference), c.algorithm == reference.algorithm)

    def final(c: Condition) -> list[float]:
        return [r.hypervolume for r in of(c)]

    def best(c: Condition) -> list[float]:
        return [r.best_f_acc * 1000 for r in of(c)]

    # One family for every hypervolume claim (each condition at the budget and at each fixed
    # budget), one for the best errors: Holm within each.
    raw_hv = {(c, FINAL): against(final, c) for c in others} | {
        (c, b): against(functools.partial(at_budget, b=b), c) for b in fixed for c in others
    }
    raw_acc = {c: against(best, c) for c in others}
    hypervolume, accuracy = holm_adjusted(raw_hv), holm_adjusted(raw_acc)
    first_algorithm = [r for c in conditions if c.algorithm == reference.algorithm for r in of(c)]
    rule_check = check_rule(first_algorithm)
    rule_comparison = f"{reference.algorithm}: at the budget vs at the convergence rule's stop"

    def row(
        c: Condition, metric: str, raw: stats.Comparison, adjusted: stats.Comparison
    ) -> stats.StatsRow:
        return stats.StatsRow(NAME, f"{c.name} vs {reference.name}", metric, raw, adjusted.p_value)

    experiment.write_stats(
        [row(c, "hypervolume", raw_hv[(c, FINAL)], hypervolume[(c, FINAL)]) for c in others]
        + [row(c, "best_f_acc_mm", raw_acc[c], accuracy[c]) for c in others]
        + [
            row(c, f"hypervolume_at_{b}", raw_hv[(c, b)], hypervolume[(c, b)])
            for b in fixed
            for c in others
        ]
        + (
            [stats.StatsRow(NAME, rule_comparison, "hypervolume", rule_check, rule_check.p_value)]
            if rule_check
            else []
        )
    )
    summaries = [
        summary(
            c, of(c), [to_target[(c, r)] for r in range(reps)], [at_budget(c, b) for b in fixed]
        )
        for c in conditions
    ]
    classical_name = f"classical rule ({len(classical_gains)} controllers)"
    baselines = {
        classical_name: _scores(classical, normalisation, penalised),
        "default gains": _scores([default], normalisation, penalised),
    }
    fronts = {
        c: [measured(front_points(records[(c, r)]), penalised) for r in range(reps)]
        for c in conditions
    }

    def fronts_at(c: Condition, b: int | str) -> list[list[Point]]:
        """Each repetition's feasible front after `b` evaluations (FINAL: its own front)."""
        if b == FINAL:
            return fronts[c]
        return [first_front(records[(c, r)], int(b), penalised) for r in range(reps)]

    attainment = {
        (c, b): attainment_difference(fronts_at(reference, b), fronts_at(c, b), normalisation)
        for b in [*fixed, FINAL]
        for c in others
    }
    figure(
        experiment.out / FIGURE,
        {c.name: fronts[c] for c in conditions},
        {c.name: (at, list(np.median([r.curve for r in of(c)], axis=0))) for c in conditions},
        {
            classical_name: measured(classical, penalised),
            "default gains": measured([default], penalised),
        },
        {
            classical_name: baselines[classical_name][0],
            f"{TARGET_TEXT} of {reference.name}'s median": target,
        },
        budgets=fixed,
    )
    findings = _findings(
        reference,
        reps,
        hypervolume,
        accuracy,
        fixed,
        attainment,
        rule,
        first_algorithm,
        rule_check,
        baselines,
        summaries[0].median_hypervolume,
    )
    setup = experiment_setup(base, reps, {SPACE: (normalisation.ideal, normalisation.nadir)})
    trajectory = base.trajectories[0]
    steady = [a for a in algorithms if a in STEADY]
    told = (
        f"; {', '.join(steady)} in a steady state, asked one candidate as each result returns "
        "and told each at once (two in flight per worker), the others generationally"
        if steady
        else ""
    )
    setup += [
        f"{len(conditions)} conditions: algorithms {', '.join(algorithms)} told "
        f"{' or '.join(scalings)} objectives, each run on the {trajectory.kind} of "
        f"{trajectory.duration:g} s, stopped at the first generation at or past {budget} "
        f"evaluations{told}",
        f"objectives: f_acc and {TORQUE_TEXT[torque_measure]} (`--torque-measure "
        f"{torque_measure}`); f_t on a log scale in every hypervolume, a choice of this project's "
        "(the paper normalises linearly)",
        "hypervolume: of each run's front (the non-dominated set of every feasible point it "
        "evaluated)"
        + (
            f", and of the feasible front of its first {', '.join(map(str, fixed))} evaluations "
            "(in the order told)"
            if fixed
            else ""
        )
        + f"; evaluations to {TARGET_TEXT}: the first multiple of the population (or the "
        "budget) at which the non-dominated set of the run's first evaluations reaches "
        f"{TARGET_TEXT} of {reference.name}'s median final hypervolume ({target:.4f})",
        f"every condition against {reference.name}: Mann-Whitney U between algorithms (they "
        "share at most a first population), Wilcoxon signed-rank, paired by seed, for the same "
        "algorithm told other objectives (the same first population, the same operators); "
        f"Holm's adjustment over the {len(hypervolume)} hypervolume comparisons (every "
        f"condition at every budget) and over the {len(accuracy)} best-error ones (`p_holm` "
        "in `stats.csv`)",
        "attainment differences: the share of the box the median attainment surface of one "
        "condition dominates and the other's does not, each way (descriptive: one number per "
        "pair of conditions, no test)",
        f"no-GA baseline: the per-joint rule Kp = ω² M_ii, Kd = 2ζω M_ii (analytic.classical), "
        f"{len(classical_gains)} controllers, and the default gains, evaluated once on the same "
        "trajectory",
    ]
    write_experiment_report(
        experiment.out / "report.md",
        title="Optimisers compared on one budget",
        setup=setup,
        table=table(summaries, baselines, fixed),
        findings=findings,
        figures=[FIGURE],
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


def _scores(
    points: Sequence[Point], normalisation: Normalisation, penalised: frozenset[Point] | set[Point]
) -> tuple[float, float]:
    """A baseline's hypervolume and best f_acc (m; NaN if it never finished an episode)."""
    kept = measured(points, penalised)
    return normalisation.hypervolume(kept), min((p[0] for p in kept), default=math.nan)


def _findings(
    reference: Condition,
    reps: int,
    hv: Mapping[tuple[Condition, int | str], stats.Comparison],
    acc: Mapping[Condition, stats.Comparison],
    fixed: Sequence[int],
    attainment: Mapping[tuple[Condition, int | str], tuple[float, float]],
    rule: Termination,
    first_algorithm: Sequence[RunMeasure],
    rule_check: stats.Comparison | None,
    baselines: dict[str, tuple[float, float]],
    reference_median: float,
) -> str:
    """The report's findings; `hv` and `acc` Holm-adjusted (holm_adjusted), `hv` keyed by
    (condition, budget), FINAL for the run's own budget."""
    ref = condition_text(reference.algorithm, reference.scaling)
    others = list(acc)
    family = len(others)
    final = {c: hv[(c, FINAL)] for c in others}
    undecidable = [c for c, r in final.items() if not stats.decidable(r)]
    if not others:
        finding = "One condition only: nothing to compare."
    elif len(undecidable) == family:
        finding = (
            f"With {reps} repetitions per condition and {len(hv)} hypervolume comparisons, no "
            f"test can reach a Holm-adjusted p < {stats.ALPHA:g} whatever the data: cannot "
            f"decide whether any condition beats {ref}; more repetitions are needed."
        )
    else:
        better = [c.name for c, r in final.items() if stats.better(r) == "a"]
        worse = [c.name for c, r in final.items() if stats.better(r) == "b"]
        finding = (
            f"By final hypervolume, {len(better)} of {family} conditions beat {ref} "
            f"significantly ({', '.join(better) or 'none'}) and {len(worse)} fall short of it "
            f"({', '.join(worse) or 'none'})."
        )
        if undecidable:
            finding += (
                f" {len(undecidable)} comparisons ({', '.join(c.name for c in undecidable)}) "
                f"cannot be decided with {reps} repetitions whatever the data; more repetitions "
                "are needed."
            )
    budgets = [*fixed, FINAL]
    lines = [
        finding,
        "",
        f"Each condition against {ref} (two-sided, alpha {stats.ALPHA:g}; the p-values below "
        f"are Holm-adjusted over the {len(hv)} hypervolume comparisons, every condition at every "
        f"budget, and over the {family} best-error ones):",
    ]
    for c in others:
        name = condition_text(c.algorithm, c.scaling)
        lines += [
            f"- {name}, hypervolume: " + stats.decide(hv[(c, FINAL)], name, ref),
            *(
                f"- {name}, hypervolume after {b} evaluations: "
                + stats.decide(hv[(c, b)], name, ref)
                for b in fixed
            ),
            f"- {name}, best error: " + stats.decide(acc[c], name, ref, higher_is_better=False),
        ]
    if others:
        lines += [
            "",
            "Attainment differences (descriptive): the share of the box the median run of one "
            "condition attains and the other's does not"
            + (f", after {', '.join(map(str, fixed))} evaluations and at the end" if fixed else "")
            + ":",
        ]
        for c in others:
            shares = "; ".join(
                f"{'at the end' if b == FINAL else f'after {b}'}: "
                f"{attainment[(c, b)][0]:.4f} only {reference.name}, "
                f"{attainment[(c, b)][1]:.4f} only {c.name}"
                for b in budgets
            )
            lines.append(f"- {c.name} against {reference.name}: {shares}")
    lines += ["", "No-GA baselines, one deterministic set each (reported, not tested):"]
    lines += [
        f"- {name}: hypervolume {value:.4f} (the median {ref} run: {reference_median:.4f}), best "
        f"error {best * 1000:.3f} mm"
        for name, (value, best) in baselines.items()
    ]
    stops = [r.stopped_by_rule_at for r in first_algorithm if r.stopped_by_rule_at is not None]
    rule_text = f"The convergence rule ({rule.rule}, on each run's own hypervolume) "
    if rule_check is None:
        lines += [
            "",
            rule_text + f"would have stopped none of the {reference.algorithm} runs "
            "within the budget: nothing to check.",
        ]
    else:
        still = stats.better(rule_check) == "a"
        conclusion = (
            "the rule stops while the experiment's measure still climbs significantly"
            if still
            else "no significant climb after the rule's stop"
            if stats.decidable(rule_check)
            else "whether the measure still climbs after the rule's stop cannot be decided"
        )
        lines += [
            "",
            rule_text + f"would have stopped {len(stops)} of {len(first_algorithm)} "
            f"{reference.algorithm} runs within the budget, after a median of "
            f"{statistics.median(stops):.0f} evaluations, at a median hypervolume of "
            f"{rule_check.median_b:.4f} against {rule_check.median_a:.4f} at the full budget: "
            + stats.decide(rule_check, "the full budget", "the rule's stop")
            + f". So {conclusion}.",
        ]
    return "\n".join(lines)


def condition_text(algorithm: str, scaling: str) -> str:
    """An optimiser and what it is told, as a reader says it: 'NSGA-II, log f_t'."""
    told = "log f_t" if scaling == "log" else scaling
    return f"{ALGORITHM_NAMES.get(algorithm, algorithm)}, {told}"


def table(
    summaries: Sequence[ConditionSummary],
    baselines: dict[str, tuple[float, float]],
    fixed: Sequence[int] = (),
) -> list[str]:
    """One row per condition, then one per no-GA baseline (`baselines`: its name → its
    hypervolume and best f_acc in m, one deterministic set each, so no spread); a column of
    median hypervolumes per fixed budget (`fixed`)."""
    rows = []
    for s in summaries:
        low, high = s.hypervolume_quartiles
        reached = (
            "not reached"
            if math.isinf(s.median_evaluations_to_target)
            else f"{s.median_evaluations_to_target:.0f}"
        )
        rows.append(
            [
                condition_text(s.algorithm, s.scaling),
                s.runs,
                f"{s.median_hypervolume:.4f}",
                f"{low:.4f}-{high:.4f}",
                *(f"{value:.4f}" for value in s.median_at_budgets),
                f"{s.median_best_f_acc * 1000:.3f}",
                f"{reached} ({s.reached_target} of {s.runs} runs reach it)",
            ]
        )
    rows += [
        [
            f"{name}, no GA",
            "–",
            f"{hypervolume:.4f}",
            "–",
            *("–" for _ in fixed),
            f"{best_f_acc * 1000:.3f}",
            "–",
        ]
        for name, (hypervolume, best_f_acc) in baselines.items()
    ]
    return markdown_table(
        [
            "condition",
            "runs",
            "median hypervolume",
            "interquartile range",
            *(f"median hypervolume after {b}" for b in fixed),
            "median best error (mm)",
            "median evaluations to 99 %",
        ],
        rows,
    )


def figure(
    path: Path,
    fronts: dict[str, list[list[Point]]],
    curves: dict[str, tuple[Sequence[int], Sequence[float]]],
    baselines: dict[str, Sequence[Point]] | None = None,
    levels: dict[str, float] | None = None,
    budgets: Sequence[int] = (),
) -> None:
    """The optimiser comparison. Left: each condition's median attainment surface (`fronts`:
    one front per repetition), with the no-GA baselines' points on top (`baselines`: the
    classical rule's controllers, the default gains). Right: each condition's median
    hypervolume against evaluations spent (`curves`: evaluations, hypervolumes), with
    `levels` (the classical rule's hypervolume, the target a run must reach) as lines, and the
    fixed `budgets` the runs are compared at as vertical ones."""
    canvas = new_figure((13, 5))
    left, right = canvas.subplots(1, 2)
    attainment_panel(left, fronts, "median attainment per condition")
    drawn = False
    for (label, points), marker in zip((baselines or {}).items(), "xs^dv", strict=False):
        kept = [p for p in points if math.isfinite(p[0]) and math.isfinite(p[1]) and p[0] < 1.0]
        if kept:
            drawn = True
            left.scatter(
                [p[0] * 1000 for p in kept],
                [max(p[1], 1e-12) for p in kept],
                marker=marker,
                color="black",
                s=24,
                label=label,
                zorder=3,
            )
    if drawn:
        left.set_yscale("log")
        left.legend(fontsize=7)
    for label, (evaluations, hypervolumes) in curves.items():
        right.plot(list(evaluations), list(hypervolumes), marker=".", label=label)
    for budget in budgets:  # where the runs are compared besides the end
        right.axvline(budget, color="0.8", linewidth=0.8)
    for (label, level), style in zip((levels or {}).items(), ("--", ":", "-."), strict=False):
        right.axhline(level, color="0.4", linestyle=style, linewidth=1, label=label)
    right.set(
        xlabel="evaluations",
        ylabel="median hypervolume (experiment normalised)",
        title="hypervolume against evaluations",
    )
    right.grid(True, alpha=0.3)
    if curves or levels:
        right.legend(fontsize=7)
    save_png(canvas, path)


def _names(allowed: Sequence[str], what: str) -> Callable[[str], list[str]]:
    """A parser of comma-separated names, each one of `allowed`, none twice."""

    def parse(text: str) -> list[str]:
        names = [part.strip() for part in text.split(",")]
        check_names(names, allowed, what)
        return names

    return parse


def _budgets(text: str) -> list[int]:
    """Positive evaluation counts, comma-separated."""
    values = numbers(int)(text)
    if any(value < 1 for value in values):
        raise ValueError(f"budgets are positive numbers of evaluations, got {text!r}")
    return values


def _torque_measure(text: str) -> str:
    if text not in TORQUE_MEASURES:
        raise ValueError(f"unknown torque measure {text!r}: one of {', '.join(TORQUE_MEASURES)}")
    return text


def prepare(base: RunConfig, options: Mapping[str, Any]) -> RunConfig:
    """The base configuration on the budget every run gets; ValueError, naming the option, for
    a budget of generations or an algorithm this installation cannot run."""
    if base.generations is not None:
        raise ValueError(
            "--generations: the algorithms experiment compares on a budget of evaluations "
            f"(--evaluations, default {DEFAULT_BUDGET}), not of generations"
        )
    try:
        check_runnable(options.get("algorithms", ALGORITHMS), base.pop)
    except ValueError as error:
        raise ValueError(f"--algorithms: {error}") from None
    if base.evaluations is None:
        return base.model_copy(update={"evaluations": DEFAULT_BUDGET})
    return base


EXPERIMENT = ExperimentSpec(
    name=NAME,
    summary="the optimisers compared on one budget of evaluations, with a classical baseline",
    run=run,
    help="Compare the optimisers the paper left open: each of --algorithms told each "
    "--objective-scaling, --reps runs each on the spiral of --duration, every run on the same "
    f"budget of --evaluations (default {DEFAULT_BUDGET}; TPE told one result at a time), "
    "against the first algorithm listed, at the budget and after each of --budgets, with the "
    "classical per-joint PD rule as a baseline without a genetic algorithm; and a check of the "
    "convergence rule the other experiments stop by.",
    options=(
        Option(
            "--algorithms",
            "algorithms",
            "the optimisers compared, comma-separated; the first is the reference every other "
            f"is tested against. Each run gets --evaluations (default {DEFAULT_BUDGET})",
            ",".join(ALGORITHMS),
            _names(ALGORITHMS, "algorithm"),
            "NAME,...",
        ),
        Option(
            "--objective-scaling",
            "scalings",
            "what each optimiser is told, comma-separated: " + ", ".join(OBJECTIVE_SCALINGS),
            defaults.OBJECTIVE_SCALING,
            _names(OBJECTIVE_SCALINGS, "objective scaling"),
            "NAME,...",
        ),
        Option(
            "--budgets",
            "budgets",
            "evaluations, comma-separated, after which every run's hypervolume is compared too "
            "(those below --evaluations; the budget itself always is)",
            ",".join(map(str, FIXED_BUDGETS)),
            _budgets,
            "N,...",
        ),
        Option(
            "--torque-measure",
            "torque_measure",
            "the f_t every run minimises: raw, the paper's Eq. 1 (squared torque changes summed "
            "over the joints, so A1 and A2 dominate it), or per-joint, each joint's change "
            "weighed by its torque limit (f_t_joint)",
            "raw",
            _torque_measure,
            "|".join(TORQUE_MEASURES),
        ),
    ),
    prepare=prepare,
)
