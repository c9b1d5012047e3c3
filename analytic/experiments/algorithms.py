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

Every number is taken in one normalisation of the experiment (analytic.experiments.normalisation),
from every run's front, penalty points left out (the baselines are measured in it, not part of it;
analytic.experiments.algorithms_measures measures, analytic.experiments.algorithms_report writes):

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
import statistics
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.algorithms_measures import (
    FINAL,
    SPACE,
    TARGET,
    TARGET_TEXT,
    TORQUE_MEASURES,
    Condition,
    RunMeasure,
    against_reference,
    attainment_difference,
    check_rule,
    checkpoints,
    evaluations_to,
    first_front,
    measure,
    measured,
    scores_in,
    summary,
)
from gainfarm.analytic.experiments.algorithms_report import (
    Plan,
    figure,
    findings,
    setup_lines,
    table,
)
from gainfarm.analytic.experiments.classical import classical_baseline
from gainfarm.analytic.experiments.normalisation import Point, front_points
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option, numbers
from gainfarm.analytic.experiments.report import write_experiment_report
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.experiments.statistics import holm_adjusted
from gainfarm.analytic.tuning import defaults
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import ALGORITHMS, OBJECTIVE_SCALINGS, optimiser
from gainfarm.analytic.tuning.records import RunRecord
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.analytic.tuning.termination import Termination
from gainfarm.schemas.gains import PDGains

NAME = "algorithms"
DEFAULT_BUDGET = 600  # evaluations per run: 20 generations of the default population of 30
# Where else each run's hypervolume is compared: how fast a method gets there matters as much as
# where it ends (random search ends close to NSGA-II on the default problem).
FIXED_BUDGETS = (100, 300)
FIGURE = "algorithms.png"


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


# --- the experiment ----------------------------------------------------------------------------


def baseline_points(
    experiment: Experiment, base: RunConfig
) -> tuple[list[PDGains], list[Point], Point]:
    """The classical rule's controllers for the base plant, and their points and the default
    gains' on the base trajectory, simulated once (one cross-evaluation, "baselines")."""
    classical = classical_baseline(base.plant, space=base.space)
    points = experiment.evaluate_gains(
        "baselines", [*classical.gains, base.default_gains], base.trajectories[0], base
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
    records = tune_conditions(experiment, base, conditions, reps)
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

    experiment.write_results(result_rows(runs, at, fixed, to_target))
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
    experiment.write_stats(
        stats_rows(reference, others, fixed, (raw_hv, hypervolume), (raw_acc, accuracy), rule_check)
    )
    summaries = [
        summary(
            c, of(c), [to_target[(c, r)] for r in range(reps)], [at_budget(c, b) for b in fixed]
        )
        for c in conditions
    ]
    classical_name = f"classical rule ({len(classical_gains)} controllers)"
    baselines = {
        classical_name: scores_in(classical, normalisation, penalised),
        "default gains": scores_in([default], normalisation, penalised),
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
    stated = findings(
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
    write_experiment_report(
        experiment.out / "report.md",
        title="Optimisers compared on one budget",
        setup=setup_lines(
            base,
            reps,
            normalisation,
            Plan(algorithms, scalings, budget, fixed, torque_measure),
            target,
            (len(hypervolume), len(accuracy)),
            len(classical_gains),
        ),
        table=table(summaries, baselines, fixed),
        findings=stated,
        figures=[FIGURE],
    )


def tune_conditions(
    experiment: Experiment, base: RunConfig, conditions: Sequence[Condition], reps: int
) -> dict[tuple[Condition, int], RunRecord]:
    """Every condition's `reps` runs (seed = rep), tuned at once: by (condition, rep)."""
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
    return {key: tuned[name] for key, name in names.items()}


def result_rows(
    runs: Mapping[tuple[Condition, int], RunMeasure],
    at: Sequence[int],
    fixed: Sequence[int],
    to_target: Mapping[tuple[Condition, int], int | None],
) -> list[dict[str, object]]:
    """results.csv: a row per run."""
    return [
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


def stats_rows(
    reference: Condition,
    others: Sequence[Condition],
    fixed: Sequence[int],
    hypervolume: tuple[Mapping[Any, stats.Comparison], Mapping[Any, stats.Comparison]],
    accuracy: tuple[Mapping[Any, stats.Comparison], Mapping[Any, stats.Comparison]],
    rule_check: stats.Comparison | None,
) -> list[stats.StatsRow]:
    """stats.csv: each condition against `reference` (`hypervolume` and `accuracy`: the raw
    comparisons and the Holm-adjusted ones), and the rule's check."""
    (raw_hv, adjusted_hv), (raw_acc, adjusted_acc) = hypervolume, accuracy
    rule_comparison = f"{reference.algorithm}: at the budget vs at the convergence rule's stop"

    def row(
        c: Condition, metric: str, raw: stats.Comparison, adjusted: stats.Comparison
    ) -> stats.StatsRow:
        return stats.StatsRow(NAME, f"{c.name} vs {reference.name}", metric, raw, adjusted.p_value)

    return (
        [row(c, "hypervolume", raw_hv[(c, FINAL)], adjusted_hv[(c, FINAL)]) for c in others]
        + [row(c, "best_f_acc_mm", raw_acc[c], adjusted_acc[c]) for c in others]
        + [
            row(c, f"hypervolume_at_{b}", raw_hv[(c, b)], adjusted_hv[(c, b)])
            for b in fixed
            for c in others
        ]
        + (
            [stats.StatsRow(NAME, rule_comparison, "hypervolume", rule_check, rule_check.p_value)]
            if rule_check
            else []
        )
    )


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
