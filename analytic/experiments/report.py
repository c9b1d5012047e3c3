"""The report and the figures the experiments share: how an experiment was run, its tables, the
frame of its report.md, and the median attainment surfaces its figures draw."""

import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import moocore

from gainfarm.analytic.experiments.normalisation import Point
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.view.reports import plant_text
from gainfarm.edges.files import write_atomically


def experiment_setup(
    base: RunConfig,
    reps: int,
    normalisations: Mapping[str, tuple[tuple[float, float], ...]],
    *,
    populations: Sequence[int] = (),
    durations: Sequence[float] = (),
) -> list[str]:
    """How an experiment was run, as its report lists it; `normalisations`: per problem (the
    trajectory fronts are judged on), the ideal and nadir points the hypervolume spans.
    `populations` and `durations`: what the runs used when they vary (the popsize and speed
    experiments), else the base configuration's population and trajectory duration hold."""
    population = (
        "populations " + ", ".join(str(size) for size in populations)
        if populations
        else f"population {base.pop}"
    )
    seconds = durations or sorted({t.duration for t in base.trajectories})
    duration = (
        ("trajectory durations " if len(seconds) > 1 else "trajectory duration ")
        + ", ".join(f"{d:g}" for d in seconds)
        + " s"
    )
    spaces = "; ".join(
        f"{problem}: f_acc {ideal[0]:.4g}-{nadir[0]:.4g} m, "
        f"f_t {ideal[1]:.4g}-{nadir[1]:.4g} (N·m)²"
        for problem, (ideal, nadir) in normalisations.items()
    )
    return [
        f"{reps} repetitions (seeds 0..{reps - 1}); runs of {population}, {duration}, "
        f"{base.termination_text}, {plant_text(base.plant)}",
        "hypervolume normalised between the ideal and the nadir of the pooled non-dominated "
        f"front of each problem (penalty points left out; f_t on a log scale): {spaces} "
        "(`normalisation.json`)",
        "comparisons: Mann-Whitney U (Wilcoxon signed-rank when paired), Vargha-Delaney A12 = "
        "P(a > b) + 0.5 P(a = b), bootstrap 95 % CI of the difference of medians "
        "(`stats.csv`); alpha 0.05",
        "runs in `runs/`, raw numbers in `results.csv`",
    ]


def markdown_table(
    header: Sequence[str], rows: Iterable[Sequence[object]], text_columns: int = 1
) -> list[str]:
    """A Markdown table, a line each: the first `text_columns` columns left-aligned, the rest
    (numbers) right-aligned."""
    return [
        "| " + " | ".join(header) + " |",
        "|" + "---|" * text_columns + "---:|" * (len(header) - text_columns),
        *("| " + " | ".join(map(str, row)) + " |" for row in rows),
    ]


def write_experiment_report(
    path: Path,
    *,
    title: str,
    setup: Sequence[str],
    table: Sequence[str],
    findings: str,
    figures: Sequence[str],
) -> None:
    """An experiment's report.md: how it was run, its table, its findings and its figures."""
    lines = [
        f"# {title}",
        "",
        *[f"- {line}" for line in setup],
        "",
        *table,
        "",
        findings,
        "",
        *[f"![{name}]({name})" for name in figures],
        "",
    ]
    write_atomically(Path(path), "\n".join(lines).encode())


def median_attainment(point_sets: Sequence[Sequence[Point]]) -> list[Point]:
    """The median (50 %) empirical attainment surface of `point_sets` (one set per repetition),
    sorted by f_acc; penalty points (f_acc ≥ 1 m, non-finite) left out."""
    points, sets = [], []
    for index, per_rep in enumerate(point_sets, start=1):
        for f_acc, f_t in per_rep:
            if math.isfinite(f_acc) and math.isfinite(f_t) and f_acc < 1.0:
                points.append((f_acc, f_t))
                sets.append(index)
    if not points:
        return []
    surface = moocore.eaf(points, sets, percentiles=[50])
    return sorted((float(row[0]), float(row[1])) for row in surface)


def attainment_panel(
    axes: Any, conditions: Mapping[str, Sequence[Sequence[Point]]], title: str
) -> None:
    """Median attainment surfaces, one step line per condition, f_acc in mm
    against f_t on a log axis."""
    drawn = False
    for label, point_sets in conditions.items():
        surface = median_attainment(point_sets)
        if not surface:
            continue
        drawn = True
        axes.step(
            [p[0] * 1000 for p in surface],
            [max(p[1], 1e-12) for p in surface],
            where="post",
            marker=".",
            label=f"{label} (median attainment)",
        )
    axes.set(xlabel="f_acc (mm)", ylabel="f_t ((N·m)²)", title=title)
    if drawn:
        axes.set_yscale("log")
        axes.legend(fontsize=7)
