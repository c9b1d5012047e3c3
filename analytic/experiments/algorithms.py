"""The optimiser comparison the paper left open: which algorithm, told which objectives, finds
the better front on one budget of evaluations; what the classical per-joint rule reaches with
no genetic algorithm at all; and whether the run-level convergence rule stops a run while it
still gains.

For each algorithm (analytic.evolution.ALGORITHMS) and objective scaling (OBJECTIVE_SCALINGS),
`reps` tuning runs (seed = rep; Experiment.tune, so kept, resumed or started) on the base spiral,
each stopped at the first generation at or past the same budget (the base configuration's
evaluations); and the classical rule's controllers (analytic.classical) with the default gains,
evaluated once on the same spiral: a no-GA baseline, one deterministic set, so reported, not
tested.

Every number is taken in one normalisation of the experiment (base.Normalisation), from
every run's front, penalty points left out (the baselines are measured in it, not part of it):

- hypervolume: of the run's front (front.json, RunRecord.front), the non-dominated set of every
  point it evaluated, as validation by replication left them (evaluated.csv carries the same
  corrections, but a run from before it did not).
- best f_acc: the front's smallest mean error, in mm.
- evaluations to 99 %: the first checkpoint (every `pop` evaluations, and the budget) at which
  the non-dominated set of the run's first evaluations (evaluated.csv: the one record of their
  order) reaches 99 % of the reference condition's median final hypervolume.
- the convergence rule's stop: where the convergence rule of the base configuration (tolerance
  and window: analytic.termination, by default Termination()'s) would have stopped the run, on
  its own per-generation hypervolumes (history.csv), and the experiment's hypervolume of its first
  evaluations up to there.

Each condition is compared with the first (the reference: the first algorithm told the first
scaling, nsga2 raw by default) on final hypervolume and best f_acc, Holm-adjusted within each
family; and, on the first algorithm's runs, the hypervolume at the rule's stop against the
hypervolume at the full budget, paired by run. Written: results.csv (a row per run), stats.csv,
normalisation.json, algorithms.png and report.md.
"""

import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.base import (
    Experiment,
    ExperimentSpec,
    Normalisation,
    Option,
    Point,
    attainment_panel,
    experiment_setup,
    front_points,
    is_penalty,
    markdown_table,
    non_dominated,
    write_experiment_report,
)
from gainfarm.analytic.experiments.classical import classical_baseline
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
DEFAULT_BUDGET = 600  # evaluations per run: 20 generations of the default population of 30
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


def checkpoints(pop: int, budget: int) -> list[int]:
    """Where a run's progress is measured: after every `pop` evaluations (a generation), and at
    the budget."""
    return [*range(pop, budget, pop), budget]


def hypervolume_curve(
    evaluated: Sequence[Point],
    at: Sequence[int],
    normalisation: Normalisation,
    penalised: frozenset[Point] | set[Point] = frozenset(),
) -> list[float]:
    """The hypervolume of the non-dominated set of the first k points of `evaluated`, for each k
    of `at` (ascending), kept as a running front so that each point is sorted in once."""
    front: list[Point] = []
    done = 0
    curve = []
    for k in at:
        front = non_dominated(front + measured(evaluated[done:k], penalised))
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
    return RunMeasure(
        evaluations=record.evaluations,
        hypervolume=normalisation.hypervolume(front),
        best_f_acc=min((f_acc for f_acc, _ in front), default=math.nan),
        curve=hypervolume_curve(record.evaluated, at, normalisation, penalised),
        stopped_by_rule_at=stop,
        hv_at_rule_stop=(
            None
            if stop is None
            else hypervolume_curve(record.evaluated, [stop], normalisation, penalised)[0]
        ),
    )


def summary(
    condition: Condition, runs: Sequence[RunMeasure], to_target: Sequence[int | None]
) -> ConditionSummary:
    """`condition`'s runs as the report's table shows them; a run that never reaches the target
    counts as needing more than any budget."""
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
) -> None:
    """Tune with each algorithm told each scaling (default: the base's), `reps` runs each on
    `base.evaluations`; evaluate the classical rule; compare, draw and report."""
    budget = base.evaluations
    if budget is None:
        raise ValueError("the algorithms experiment compares on one budget: give base.evaluations")
    scalings = tuple(scalings or (base.objective_scaling,))
    check_names(algorithms, ALGORITHMS, "algorithm")
    check_names(scalings, OBJECTIVE_SCALINGS, "objective scaling")
    check_runnable(algorithms, base.pop)
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
    at = checkpoints(base.pop, budget)
    # The rule a run of this configuration stops by when it has no budget.
    rule = Termination(tolerance=base.tolerance, window=base.window)
    runs = {
        key: measure(record, normalisation, at, rule, penalised) for key, record in records.items()
    }
    reference = conditions[0]
    target = TARGET * statistics.median(runs[(reference, r)].hypervolume for r in range(reps))
    to_target = {key: evaluations_to(run.curve, at, target) for key, run in runs.items()}
    experiment.write_results(
        [
            {
                "algorithm": condition.algorithm,
                "scaling": condition.scaling,
                "rep": rep,
                "seed": rep,
                "evaluations": run.evaluations,
                "hypervolume": run.hypervolume,
                "best_f_acc_mm": run.best_f_acc * 1000,
                "evaluations_to_99": to_target[(condition, rep)],
                "stopped_by_rule_at": run.stopped_by_rule_at,
                "hv_at_rule_stop": run.hv_at_rule_stop,
            }
            for (condition, rep), run in runs.items()
        ]
    )

    def of(condition: Condition) -> list[RunMeasure]:
        return [runs[(condition, rep)] for rep in range(reps)]

    others = conditions[1:]
    hypervolume = {
        c: against_reference(
            [r.hypervolume for r in of(c)],
            [r.hypervolume for r in of(reference)],
            c.algorithm == reference.algorithm,
        )
        for c in others
    }
    accuracy = {
        c: against_reference(
            [r.best_f_acc * 1000 for r in of(c)],
            [r.best_f_acc * 1000 for r in of(reference)],
            c.algorithm == reference.algorithm,
        )
        for c in others
    }
    first_algorithm = [r for c in conditions if c.algorithm == reference.algorithm for r in of(c)]
    rule_check = check_rule(first_algorithm)
    rule_comparison = f"{reference.algorithm}: at the budget vs at the convergence rule's stop"
    experiment.write_stats(
        [
            stats.StatsRow(NAME, f"{c.name} vs {reference.name}", metric, results[c])
            for metric, results in (("hypervolume", hypervolume), ("best_f_acc_mm", accuracy))
            for c in others
        ]
        + ([stats.StatsRow(NAME, rule_comparison, "hypervolume", rule_check)] if rule_check else [])
    )
    summaries = [summary(c, of(c), [to_target[(c, r)] for r in range(reps)]) for c in conditions]
    classical_name = f"classical rule ({len(classical_gains)} controllers)"
    baselines = {
        classical_name: _scores(classical, normalisation, penalised),
        "default gains": _scores([default], normalisation, penalised),
    }
    figure(
        experiment.out / FIGURE,
        {
            c.name: [measured(front_points(records[(c, r)]), penalised) for r in range(reps)]
            for c in conditions
        },
        {c.name: (at, list(np.median([r.curve for r in of(c)], axis=0))) for c in conditions},
        {
            classical_name: measured(classical, penalised),
            "default gains": measured([default], penalised),
        },
        {
            classical_name: baselines[classical_name][0],
            f"{TARGET_TEXT} of {reference.name}'s median": target,
        },
    )
    verdict = _verdict(
        reference,
        reps,
        hypervolume,
        accuracy,
        rule,
        first_algorithm,
        rule_check,
        baselines,
        summaries[0].median_hypervolume,
    )
    setup = experiment_setup(base, reps, {SPACE: (normalisation.ideal, normalisation.nadir)})
    trajectory = base.trajectories[0]
    setup += [
        f"{len(conditions)} conditions: algorithms {', '.join(algorithms)} told "
        f"{' or '.join(scalings)} objectives, each run on the {trajectory.kind} of "
        f"{trajectory.duration:g} s, stopped at the first generation at or past {budget} "
        "evaluations",
        "hypervolume: of each run's front (the non-dominated set of every point it evaluated); "
        f"evaluations to {TARGET_TEXT}: the first multiple of the population (or the budget) at "
        "which the non-dominated set of the run's first evaluations reaches "
        f"{TARGET_TEXT} of {reference.name}'s median final hypervolume ({target:.4f})",
        f"every condition against {reference.name}: Mann-Whitney U between algorithms (they "
        "share at most a first population), Wilcoxon signed-rank, paired by seed, for the same "
        "algorithm told other objectives (the same first population, the same operators); "
        "Holm's adjustment within the hypervolume comparisons and within the best-error ones",
        f"no-GA baseline: the per-joint rule Kp = ω² M_ii, Kd = 2ζω M_ii (analytic.classical), "
        f"{len(classical_gains)} controllers, and the default gains, evaluated once on the same "
        "trajectory",
    ]
    write_experiment_report(
        experiment.out / "report.md",
        title="Optimisers compared on one budget",
        setup=setup,
        table=table(summaries, baselines),
        verdict=verdict,
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


def holm_adjusted(results: dict[Condition, stats.Comparison]) -> dict[Condition, stats.Comparison]:
    """The comparisons with Holm-adjusted p-values (one family: all of them), and with the
    smallest adjusted p-value each can reach: Holm multiplies the family's smallest p by the
    family's size, so with many comparisons a sample size that could decide one test alone
    may no longer decide any."""
    if not results:
        return {}
    adjusted = stats.holm([r.p_value for r in results.values()])
    tested = [r.min_p for r in results.values() if math.isfinite(r.p_value)]
    floor = len(tested) * min(tested, default=0.0)
    return {
        c: replace(r, p_value=p, min_p=min(1.0, max(r.min_p, floor)))
        for (c, r), p in zip(results.items(), adjusted, strict=True)
    }


def _verdict(
    reference: Condition,
    reps: int,
    hypervolume: dict[Condition, stats.Comparison],
    accuracy: dict[Condition, stats.Comparison],
    rule: Termination,
    first_algorithm: Sequence[RunMeasure],
    rule_check: stats.Comparison | None,
    baselines: dict[str, tuple[float, float]],
    reference_median: float,
) -> str:
    ref = condition_text(reference.algorithm, reference.scaling)
    family = len(hypervolume)
    hv, acc = holm_adjusted(hypervolume), holm_adjusted(accuracy)
    undecidable = [c for c, r in hv.items() if not stats.decidable(r)]
    if not hypervolume:
        finding = "One condition only: nothing to compare."
    elif len(undecidable) == family:
        finding = (
            f"With {reps} repetitions per condition and {family} comparisons, no test can reach "
            f"a Holm-adjusted p < {stats.ALPHA:g} whatever the data: cannot decide whether any "
            f"condition beats {ref}; more repetitions are needed."
        )
    else:
        better = [c.name for c, r in hv.items() if stats.better(r) == "a"]
        worse = [c.name for c, r in hv.items() if stats.better(r) == "b"]
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
    lines = [
        finding,
        "",
        f"Each condition against {ref} (two-sided, alpha {stats.ALPHA:g}; the p-values below "
        f"are Holm-adjusted over the {family} comparisons of each metric):",
    ]
    for c in hypervolume:
        name = condition_text(c.algorithm, c.scaling)
        lines += [
            f"- {name}, hypervolume: " + stats.decide(hv[c], name, ref),
            f"- {name}, best error: " + stats.decide(acc[c], name, ref, higher_is_better=False),
        ]
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
    summaries: Sequence[ConditionSummary], baselines: dict[str, tuple[float, float]]
) -> list[str]:
    """One row per condition, then one per no-GA baseline (`baselines`: its name → its
    hypervolume and best f_acc in m, one deterministic set each, so no spread)."""
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
                f"{s.median_best_f_acc * 1000:.3f}",
                f"{reached} ({s.reached_target} of {s.runs} runs reach it)",
            ]
        )
    rows += [
        [f"{name}, no GA", "–", f"{hypervolume:.4f}", "–", f"{best_f_acc * 1000:.3f}", "–"]
        for name, (hypervolume, best_f_acc) in baselines.items()
    ]
    return markdown_table(
        [
            "condition",
            "runs",
            "median hypervolume",
            "interquartile range",
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
) -> None:
    """The optimiser comparison. Left: each condition's median attainment surface (`fronts`:
    one front per repetition), with the no-GA baselines' points on top (`baselines`: the
    classical rule's controllers, the default gains). Right: each condition's median
    hypervolume against evaluations spent (`curves`: evaluations, hypervolumes), with
    `levels` (the classical rule's hypervolume, the target a run must reach) as lines."""
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
    f"budget of --evaluations (default {DEFAULT_BUDGET}), against the first algorithm listed, "
    "with the classical per-joint PD rule as a baseline without a genetic algorithm; and a "
    "check of the convergence rule the other experiments stop by.",
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
    ),
    prepare=prepare,
)
