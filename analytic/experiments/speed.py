"""The paper's speed experiment: `reps` runs (seed = rep) on the spiral of each duration; every
tuned front evaluated again on every other duration, so that each controller is judged both at
the speed it was tuned for and at the others.

Judged in millimetres (analytic.experiments.measures), not by the most accurate member (often a
chattering one): each front's error at one torque smoothness, the least f_t every front of the
experiment reaches on every spiral (one level for all, so that durations compare at the same
smoothness), and the error of each run's recommended controller; each with its median and 95 %
bootstrap confidence interval over the repetitions. Each duration against the next shorter one
on its own spiral, and each controller moved to another speed against the one tuned there: the
p-values of each measure's family Holm-adjusted in the report (stats.csv holds them unadjusted).

Each spiral evaluated on is a problem of its own ("on 5 s", ...: normalisation.json's keys).
Written: results.csv (a row per tuned-on and evaluated-on duration), stats.csv,
normalisation.json, speed.png and report.md.
"""

import functools
import math
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.findings import levels_off, step_comparisons
from gainfarm.analytic.experiments.measures import (
    difference,
    error_at,
    median,
    median_interval,
    recommended,
    shown,
    smoothness_level,
)
from gainfarm.analytic.experiments.normalisation import Point, front_points
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option, numbers
from gainfarm.analytic.experiments.report import attainment_panel, markdown_table
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import RunRecord
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec

NAME = "speed"
DURATIONS = (3.0, 4.0, 5.0, 6.0)
FIGURE = "speed.png"
MM = 1000.0  # mm per m
AT_LEVEL, RECOMMENDED = "error_at_level_mm", "recommended_error_mm"  # stats.csv's metrics
SAID = {AT_LEVEL: "error at the smoothness level", RECOMMENDED: "recommended controller's error"}

Pair = tuple[float, float]  # (tuned on, evaluated on), s


def run(
    experiment: Experiment, base: RunConfig, reps: int, durations: Sequence[float] = DURATIONS
) -> None:
    """Tune on spirals of each duration; evaluate every tuned front on every duration."""
    spirals = {d: TrajectorySpec(kind=TrajectoryKind.spiral, duration=d) for d in durations}

    def tuned_and_moved(tuned: float, rep: int) -> tuple[RunRecord, dict[float, list[Point]]]:
        """The run on the spiral of `tuned` s, and its front on every spiral."""
        name = f"spiral{tuned:g}s-rep{rep}"
        record = experiment.tune(
            name, base.model_copy(update={"trajectories": (spirals[tuned],), "seed": rep})
        )
        return record, {
            used: front_points(record)
            if used == tuned
            else experiment.evaluate(f"{name}-on{used:g}s", record.front, spirals[used], base)
            for used in durations
        }

    done = experiment.concurrently(
        {
            (rep, tuned): functools.partial(tuned_and_moved, tuned, rep)
            for rep in range(reps)
            for tuned in durations
        }
    )
    matrix: dict[Pair, list[list[Point]]] = {}  # each front on each spiral, a list per rep
    chosen: dict[Pair, list[Point]] = {}  # the recommended controller's point, a point per rep
    closest = 0  # runs where no member dominates the default gains: the closest is taken
    for (_, tuned), (record, on) in done.items():
        pick = recommended(record)
        closest += pick is not None and pick.name == "closest"
        index = None if pick is None else record.front.index(pick.member)
        for used in durations:
            matrix.setdefault((tuned, used), []).append(on[used])
            point = on[used][index] if index is not None else (math.nan, math.nan)
            chosen.setdefault((tuned, used), []).append(point)
    pairs = [(t, u) for t in durations for u in durations]
    level = smoothness_level([p for pair in pairs for p in matrix[pair]], experiment.penalised)
    measured = {
        AT_LEVEL: {
            pair: [error_at(p, level, experiment.penalised) * MM for p in matrix[pair]]
            for pair in pairs
        },
        RECOMMENDED: {pair: [p[0] * MM for p in chosen[pair]] for pair in pairs},
    }
    # One normalised space per trajectory evaluated on: fronts on one spiral compare.
    normalisations = {
        u: experiment.normalisation([p for t in durations for p in matrix[(t, u)]])
        for u in durations
    }
    experiment.write_normalisation({f"on {u:g} s": n for u, n in normalisations.items()})
    hypervolumes = {
        (t, u): [normalisations[u].hypervolume(p) for p in matrix[(t, u)]] for t, u in pairs
    }
    experiment.write_results(
        [
            {
                "tuned_on_s": t,
                "evaluated_on_s": u,
                "median_hypervolume": statistics.median(hypervolumes[(t, u)]),
                "f_t_level": level,
                **interval_columns("error_at_level_mm", measured[AT_LEVEL][(t, u)]),
                **interval_columns("recommended_error_mm", measured[RECOMMENDED][(t, u)]),
                "median_recommended_f_t": median([p[1] for p in chosen[(t, u)]]),
            }
            for t, u in pairs
        ]
    )
    figure(
        experiment.out / FIGURE,
        durations,
        {pair: statistics.median(values) for pair, values in hypervolumes.items()},
        {pair: median(v) / MM for pair, v in measured[AT_LEVEL].items()},
        matrix,
        {pair: median(v) / MM for pair, v in measured[RECOMMENDED].items()},
        level,
    )
    # Accuracy on its own spiral, each duration against the next shorter one (lower is better).
    falls = {
        metric: step_comparisons({d: finite(values[(d, d)]) for d in durations})
        for metric, values in measured.items()
    }
    transfers = {
        metric: {
            (t, u): stats.compare(finite(values[(t, u)]), finite(values[(u, u)]))
            for u in durations
            for t in durations
            if t != u
        }
        for metric, values in {**measured, "hypervolume": hypervolumes}.items()
    }
    experiment.write_stats(
        [
            stats.StatsRow(NAME, f"{slow:g} s vs {fast:g} s, own spiral", metric, result)
            for metric, steps in falls.items()
            for (fast, slow), result in steps.items()
        ]
        + [
            stats.StatsRow(NAME, f"tuned on {t:g} s vs tuned on {u:g} s, on {u:g} s", metric, r)
            for metric, moved in transfers.items()
            for (t, u), r in moved.items()
        ]
    )
    experiment.write_report(
        "Trajectory speed",
        base,
        reps,
        table(durations, measured, level),
        findings(durations, measured, level, falls, transfers, reps, closest),
        [FIGURE],
        {f"on {u:g} s": n for u, n in normalisations.items()},
        durations=durations,
    )


def finite(values: Sequence[float]) -> list[float]:
    """The values a test compares: a run without a measure (NaN) left out."""
    return [v for v in values if math.isfinite(v)]


def interval_columns(name: str, values: Sequence[float]) -> dict[str, float]:
    """results.csv's median and 95 % interval of one measure: median_NAME, NAME_ci_low/high."""
    median, low, high = median_interval(values)
    return {f"median_{name}": median, f"{name}_ci_low": low, f"{name}_ci_high": high}


def findings(
    durations: Sequence[float],
    measured: Mapping[str, Mapping[Pair, list[float]]],
    level: float,
    falls: Mapping[str, Mapping[Pair, stats.Comparison]],
    transfers: Mapping[str, Mapping[Pair, stats.Comparison]],
    reps: int,
    closest: int = 0,
) -> str:
    """The report's findings: how the error on its own spiral moves with the duration, at one
    smoothness and for the recommended controller, and what moving a controller to another
    speed costs; every family of tests Holm-adjusted."""
    ordered = sorted(durations)
    falls = {metric: stats.holm_adjusted(steps) for metric, steps in falls.items()}
    transfers = {metric: stats.holm_adjusted(moved) for metric, moved in transfers.items()}

    def on_own(metric: str) -> str:
        return ", ".join(f"{shown(measured[metric][(d, d)], 1)} mm at {d:g} s" for d in ordered)

    finding = levels_off(
        falls[AT_LEVEL],
        reps,
        "the error at that smoothness",
        "duration",
        "{:g} s".format,
        higher_is_better=False,
    ).text
    lines = [
        f"At one torque smoothness, f_t ≤ {level:.4g} (N·m)² (the least every front of the "
        f"experiment reaches), the error on its own spiral is (median [95 % CI]) "
        f"{on_own(AT_LEVEL)}. {finding} The recommended controller's error: "
        f"{on_own(RECOMMENDED)}"
        + (
            f" (in {closest} runs no member dominated the default gains: the closest is taken)"
            if closest
            else ""
        )
        + ". (The paper, by the most accurate controller: it falls, and levels off near 5 s.)",
        "",
        "Each duration against the next shorter, on its own spiral (two-sided, alpha "
        f"{stats.ALPHA:g}; p Holm-adjusted over the consecutive steps of each measure; the "
        "difference of the medians in mm, with its 95 % CI):",
    ]
    lines += [
        f"- {slow:g} s against {fast:g} s, {SAID[metric]}, {difference(result, 'mm')}: "
        + stats.decide(result, f"{slow:g} s", f"{fast:g} s", higher_is_better=False)
        for metric, steps in falls.items()
        for (fast, slow), result in steps.items()
    ]
    moved = transfers[RECOMMENDED]
    if moved:
        lines.append("")
        for metric, what in ((RECOMMENDED, "the recommended controller"), (AT_LEVEL, "a front")):
            cost = median(
                [
                    median(measured[metric][(t, u)]) / median(measured[metric][(u, u)]) - 1
                    for t, u in transfers[metric]
                ]
            )
            worse = sum(stats.better(r, False) == "b" for r in transfers[metric].values())
            undecidable = sum(not stats.decidable(r) for r in transfers[metric].values())
            lines.append(
                f"Run at another speed, {what} changes its error"
                + (f" at f_t ≤ {level:.4g} (N·m)²" if metric == AT_LEVEL else "")
                + f" by a median of {cost:+.0%} against the one tuned for that speed; it is "
                f"significantly worse in {worse} of {len(transfers[metric])} cases (Holm over "
                "them)"
                + (
                    f" ({undecidable} cannot be decided with {reps} repetitions)"
                    if undecidable
                    else ""
                )
                + "."
            )
        lines[-1] += " (The paper: moving a controller to another speed costs little.)"
    return "\n".join(lines)


def table(
    durations: Sequence[float], measured: Mapping[str, Mapping[Pair, list[float]]], level: float
) -> list[str]:
    """Two matrices, tuned-on duration against evaluated-on duration: the error at the
    smoothness level and the recommended controller's, in mm, median [95 % CI]."""
    lines: list[str] = []
    for metric, caption in (
        (AT_LEVEL, f"Error at f_t ≤ {level:.4g} (N·m)², mm, median [95 % CI]:"),
        (RECOMMENDED, "The recommended controller's error, mm, median [95 % CI]:"),
    ):
        lines += [
            *([""] if lines else []),
            caption,
            "",
            *markdown_table(
                ["tuned on", *(f"on {d:g} s" for d in durations)],
                (
                    [f"{t:g} s", *(shown(measured[metric][(t, u)], 1) for u in durations)]
                    for t in durations
                ),
            ),
        ]
    return lines


def text_colour(background: Sequence[float]) -> str:
    """Black or white, whichever reads better on `background` (RGB(A), 0-1): the one of
    higher WCAG contrast, from the background's relative luminance."""
    linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in background[:3]]
    luminance = 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]
    # Contrast with black (L + 0.05) / 0.05 against with white 1.05 / (L + 0.05).
    return "black" if (luminance + 0.05) ** 2 > 0.05 * 1.05 else "white"


def figure(
    path: Path,
    durations: Sequence[float],
    hypervolume: Mapping[Pair, float],
    error: Mapping[Pair, float],
    fronts: Mapping[Pair, list[list[Point]]] | None = None,
    recommended: Mapping[Pair, float] | None = None,
    level: float | None = None,
) -> None:
    """Matrices, tuned-on duration against evaluated-on duration: the median hypervolume, the
    median error at the smoothness `level` (m; f_t ≤ level) and, if given, the recommended
    controller's (m); and, if `fronts` ((tuned on, evaluated on) → one front per repetition), a
    row of median attainment surfaces, one panel per spiral evaluated on, the level drawn."""
    matrices = [
        (hypervolume, "median hypervolume (f_t on a log scale)", "{:.3f}"),
        (
            {k: v * MM for k, v in error.items()},
            f"error at f_t ≤ {level:.3g} (N·m)² (mm)"
            if level is not None
            else "error at one torque smoothness (mm)",
            "{:.2f}",
        ),
    ]
    if recommended is not None:
        matrices.append(
            ({k: v * MM for k, v in recommended.items()}, "recommended's error (mm)", "{:.2f}")
        )
    columns = max(len(matrices), len(durations)) if fronts else len(matrices)
    canvas = new_figure((5 * columns, 9 if fronts else 4.5))
    panels = canvas.subplots(2 if fronts else 1, columns, squeeze=False)
    for axes, (values, title, fmt) in zip(panels[0], matrices, strict=False):
        grid = [[values[(t, u)] for u in durations] for t in durations]
        image = axes.imshow(grid, cmap="viridis")
        for i, row in enumerate(grid):
            for j, value in enumerate(row):
                cell = image.cmap(image.norm(value))
                axes.text(
                    j, i, fmt.format(value), ha="center", va="center", color=text_colour(cell)
                )
        labels = [f"{d:g} s" for d in durations]
        axes.set(
            xticks=range(len(durations)),
            xticklabels=labels,
            yticks=range(len(durations)),
            yticklabels=labels,
            xlabel="evaluated on",
            ylabel="tuned on",
            title=title,
        )
        canvas.colorbar(image, ax=axes)
    for axes in panels[0][len(matrices) :]:
        axes.set_axis_off()
    if fronts:
        for column, used in enumerate(durations):
            axes = panels[1][column]
            attainment_panel(
                axes,
                {f"tuned on {t:g} s": fronts[(t, used)] for t in durations},
                f"fronts on the {used:g} s spiral",
            )
            if level is not None and math.isfinite(level):
                axes.axhline(level, color="grey", linestyle=":", linewidth=1)
        for axes in panels[1][len(durations) :]:
            axes.set_axis_off()
    save_png(canvas, path)


EXPERIMENT = ExperimentSpec(
    name=NAME,
    summary="the paper's trajectory speeds: tuned on each spiral duration, judged on every one",
    run=run,
    options=(
        Option(
            "--durations",
            "durations",
            "spiral durations, s, comma-separated",
            ",".join(f"{d:g}" for d in DURATIONS),
            numbers(float),
            "S,S,...",
        ),
    ),
    duration=None,  # the spirals' durations are --durations
    trajectories=lambda _base, options: [
        TrajectorySpec(duration=d) for d in options.get("durations", DURATIONS)
    ],
    trajectory_option="--durations",
)
