"""The paper's population-size experiment: for each population size, `reps` runs (seed = rep)
on the base trajectory, each to its own stop; their final hypervolumes (in one normalised space,
"all runs") and the evaluations each took, each size against the next smaller one.

Beside the hypervolume, what a step buys in physical units (analytic.experiments.measures): each
final front's error at one torque smoothness (the least f_t every run's front reaches), and the
recommended controller's error and f_t; each size's median with a 95 % bootstrap confidence
interval. The consecutive steps of each measure are one family: their p-values are
Holm-adjusted in the report (stats.csv holds them unadjusted).

Written: results.csv (a row per run), stats.csv, normalisation.json, popsize.png and report.md.
"""

import math
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.findings import levels_off, step_comparisons
from gainfarm.analytic.experiments.measures import (
    difference,
    error_at,
    recommended,
    shown,
    smoothness_level,
)
from gainfarm.analytic.experiments.normalisation import Point, front_points
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option, numbers
from gainfarm.analytic.experiments.report import attainment_panel, markdown_table
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning import defaults
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.view.figures import new_figure, save_png

NAME = "popsize"
SIZES = (10, 20, 30, 50, 80)
FIGURE = "popsize.png"
SPACE = "all runs"  # the one problem: normalisation.json's key
MM = 1000.0  # mm per m
# Each measure, as results.csv's column and stats.csv's metric → how the report says it and its
# unit. The hypervolume is better higher; the others (errors, torque change, cost) lower.
MEASURES = {
    "hypervolume": ("hypervolume", ""),
    "error_at_level_mm": ("error at the smoothness level", "mm"),
    "recommended_error_mm": ("recommended controller's error", "mm"),
    "recommended_f_t": ("recommended controller's f_t", "(N·m)²"),
    "evaluations": ("evaluations", ""),
}


def run(experiment: Experiment, base: RunConfig, reps: int, sizes: Sequence[int] = SIZES) -> None:
    """Evaluations to converge, final hypervolume and the practical measures, for each size."""
    plan = {
        (size, rep): (f"pop{size}-rep{rep}", base.model_copy(update={"pop": size, "seed": rep}))
        for size in sizes
        for rep in range(reps)
    }
    tuned = experiment.tune_many(dict(plan.values()))
    runs = {key: tuned[name] for key, (name, _) in plan.items()}
    fronts = {key: front_points(record) for key, record in runs.items()}
    normalisation = experiment.normalisation(list(fronts.values()))
    experiment.write_normalisation({SPACE: normalisation})
    level = smoothness_level(list(fronts.values()), experiment.penalised)
    picks = {key: recommended(record) for key, record in runs.items()}
    rows = []
    for (size, rep), record in runs.items():
        pick = picks[(size, rep)]
        f_acc, f_t = pick.member.objectives if pick else (math.nan, math.nan)
        rows.append(
            {
                "pop": size,
                "rep": rep,
                "seed": rep,
                "evaluations": record.evaluations,
                "hypervolume": normalisation.hypervolume(fronts[(size, rep)]),
                "error_at_level_mm": error_at(fronts[(size, rep)], level, experiment.penalised)
                * MM,
                "recommended_error_mm": f_acc * MM,
                "recommended_f_t": f_t,
                "recommended": pick.name if pick else "",
                "f_t_level": level,
                "wall_seconds": record.wall_seconds,
                "stopped": record.stopped,
            }
        )
    experiment.write_results(rows)
    values = {
        metric: {s: [float(r[metric]) for r in rows if r["pop"] == s] for s in sizes}
        for metric in MEASURES
    }
    figure(
        experiment.out / FIGURE,
        values["hypervolume"],
        {s: [int(v) for v in evaluations] for s, evaluations in values["evaluations"].items()},
        {s: [fronts[(s, rep)] for rep in range(reps)] for s in sizes},
        level,
    )
    # Each size against the next smaller one: does the larger population gain, at what cost?
    compared = {
        metric: step_comparisons({s: finite(v) for s, v in by_size.items()})
        for metric, by_size in values.items()
    }
    experiment.write_stats(
        [
            stats.StatsRow(NAME, f"pop {large} vs pop {small}", metric, result)
            for metric, steps in compared.items()
            for (small, large), result in steps.items()
        ]
    )
    closest = sum(pick is not None and pick.name == "closest" for pick in picks.values())
    experiment.write_report(
        "Population size",
        base,
        reps,
        table(values, level),
        findings(
            compared["hypervolume"],
            reps,
            {metric: steps for metric, steps in compared.items() if metric != "hypervolume"},
            closest,
        ),
        [FIGURE],
        {SPACE: normalisation},
        populations=sizes,
    )


def finite(values: Sequence[float]) -> list[float]:
    """The values a test compares: a run without a measure (NaN) left out."""
    return [v for v in values if math.isfinite(v)]


def findings(
    compared: Mapping[tuple[int, int], stats.Comparison],
    reps: int,
    practical: Mapping[str, Mapping[tuple[int, int], stats.Comparison]] | None = None,
    closest: int = 0,
) -> str:
    """Where the hypervolume (`compared`: its consecutive steps) levels off, against the
    paper's population near 30; and what each step buys or costs in the `practical` measures
    (MEASURES' names → their steps). Each measure's steps Holm-adjusted as one family."""
    hypervolume = stats.holm_adjusted(compared)
    others = {metric: stats.holm_adjusted(steps) for metric, steps in (practical or {}).items()}
    found = levels_off(hypervolume, reps, "the hypervolume", "population size")
    finding = found.text
    if found.rising:
        finding += (
            " The paper found a population near 30 the best trade-off: weigh the gains above "
            "against the evaluations each size costs."
        )
    elif found.level is not None:
        finding += " The paper found a population near 30 the best trade-off: " + (
            "this holds here." if 20 <= found.level <= 50 else "here it lies elsewhere."
        )
    if closest:
        finding += (
            f" (In {closest} runs no member dominated the default gains: their recommended "
            "controller is the one closest to dominating them.)"
        )
    lines = [
        finding,
        "",
        f"Each size against the next smaller (two-sided, alpha {stats.ALPHA:g}; p Holm-adjusted "
        "over the consecutive steps of each measure; differences in its unit):",
    ]
    for (small, large), result in hypervolume.items():
        lines.append(
            f"- pop {large} against pop {small}: "
            + stats.decide(result, f"pop {large}", f"pop {small}")
            + ("" if stats.significant(result) else f" (hypervolume {difference(result)})")
        )
        for metric, steps in others.items():
            if (small, large) in steps:
                said, unit = MEASURES[metric]
                step = steps[(small, large)]
                lines.append(
                    f"  - {said}, {difference(step, unit)}: "
                    + stats.decide(step, f"pop {large}", f"pop {small}", higher_is_better=False)
                )
    return "\n".join(lines)


def table(values: Mapping[str, Mapping[int, list[float]]], level: float) -> list[str]:
    """Per population size, the medians of each measure (`values`: MEASURES' names → size →
    one value per run), the practical ones with their 95 % confidence intervals."""
    return markdown_table(
        [
            "population",
            "median hypervolume",
            f"error at f_t ≤ {level:.4g} (N·m)², mm",
            "recommended's error, mm",
            "recommended's f_t, (N·m)²",
            "median evaluations",
        ],
        (
            [
                size,
                f"{statistics.median(values['hypervolume'][size]):.4f}",
                shown(values["error_at_level_mm"][size], 1),
                shown(values["recommended_error_mm"][size], 1),
                shown(values["recommended_f_t"][size], 1, 4),
                f"{statistics.median(values['evaluations'][size]):.0f}",
            ]
            for size in values["hypervolume"]
        ),
        text_columns=0,
    )


def figure(
    path: Path,
    hypervolumes: Mapping[int, list[float]],
    evaluations: Mapping[int, list[int]],
    fronts: Mapping[int, list[list[Point]]] | None = None,
    level: float | None = None,
) -> None:
    """Box plots per population size: final hypervolume, and evaluations to stop; and each
    size's median attainment surface, if `fronts` (per size, one front per repetition), with
    the smoothness `level` the errors are read at."""
    canvas = new_figure((15 if fronts else 10, 4))
    panels = canvas.subplots(1, 3 if fronts else 2)
    left, right = panels[0], panels[1]
    labels = [str(size) for size in hypervolumes]
    left.boxplot(list(hypervolumes.values()), tick_labels=labels)
    left.set(
        xlabel="population size",
        ylabel="hypervolume (experiment normalised, f_t on a log scale)",
        title="final hypervolume",
    )
    right.boxplot([evaluations[size] for size in hypervolumes], tick_labels=labels)
    right.set(xlabel="population size", ylabel="evaluations", title="evaluations to stop")
    if fronts:
        attainment_panel(
            panels[2], {f"pop {s}": sets for s, sets in fronts.items()}, "fronts per size"
        )
        if level is not None and math.isfinite(level):
            panels[2].axhline(level, color="grey", linestyle=":", linewidth=1)
    save_png(canvas, path)


def population_sizes(text: str) -> list[int]:
    """--sizes: comma-separated population sizes, each one a run may have."""
    sizes = numbers(int)(text)
    for size in sizes:
        if not defaults.POP_MIN <= size <= defaults.POP_MAX:
            raise ValueError(
                f"{size} is not a population size ({defaults.POP_MIN}-{defaults.POP_MAX})"
            )
    return sizes


EXPERIMENT = ExperimentSpec(
    name=NAME,
    summary="the paper's population sizes: evaluations to converge and final hypervolume",
    run=run,
    options=(
        Option(
            "--sizes",
            "sizes",
            "population sizes, comma-separated",
            ",".join(map(str, SIZES)),
            population_sizes,
            "N,N,...",
        ),
    ),
)
