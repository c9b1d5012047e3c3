"""The algorithms experiment's report (analytic.experiments.algorithms): how it was run, its
table, its findings in plain words and its figure.
"""

import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.algorithms_measures import (
    FINAL,
    SPACE,
    STEADY,
    TARGET_TEXT,
    TORQUE_TEXT,
    Condition,
    ConditionSummary,
    RunMeasure,
)
from gainfarm.analytic.experiments.normalisation import Normalisation, Point
from gainfarm.analytic.experiments.report import attainment_panel, experiment_setup, markdown_table
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.termination import Termination
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.analytic.view.reports import ALGORITHM_NAMES


@dataclass(frozen=True)
class Plan:
    """What the experiment was asked to compare, as its report's setup says it."""

    algorithms: Sequence[str]
    scalings: Sequence[str]
    budget: int
    fixed: Sequence[int]
    torque_measure: str


def setup_lines(
    base: RunConfig,
    reps: int,
    normalisation: Normalisation,
    plan: Plan,
    target: float,
    families: tuple[int, int],
    classical_controllers: int,
) -> list[str]:
    """How the experiment was run, as report.md lists it (`families`: how many hypervolume and
    best-error comparisons Holm adjusts over)."""
    algorithms, scalings, budget, fixed = plan.algorithms, plan.scalings, plan.budget, plan.fixed
    torque_measure = plan.torque_measure
    conditions = [Condition(a, s) for a in algorithms for s in scalings]
    reference = conditions[0]
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
        f"Holm's adjustment over the {families[0]} hypervolume comparisons (every "
        f"condition at every budget) and over the {families[1]} best-error ones (`p_holm` "
        "in `stats.csv`)",
        "attainment differences: the share of the box the median attainment surface of one "
        "condition dominates and the other's does not, each way (descriptive: one number per "
        "pair of conditions, no test)",
        f"no-GA baseline: the per-joint rule Kp = ω² M_ii, Kd = 2ζω M_ii (analytic.classical), "
        f"{classical_controllers} controllers, and the default gains, evaluated once on the same "
        "trajectory",
    ]
    return setup


def findings(
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
