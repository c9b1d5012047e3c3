"""The paper's speed experiment: `reps` runs (seed = rep) on the spiral of each duration; every
tuned front evaluated again on every other duration, so that each controller is judged both at
the speed it was tuned for and at the others.

Each spiral evaluated on is a problem of its own ("on 5 s", ...: normalisation.json's keys).
Written: results.csv (a row per tuned-on and evaluated-on duration), stats.csv,
normalisation.json, speed.png and report.md.
"""

import functools
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.base import (
    Experiment,
    ExperimentSpec,
    Option,
    Point,
    attainment_panel,
    front_points,
    levels_off,
    markdown_table,
    numbers,
    step_comparisons,
)
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import RunRecord
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec

NAME = "speed"
DURATIONS = (3.0, 4.0, 5.0, 6.0)
FIGURE = "speed.png"


def run(
    experiment: Experiment, base: RunConfig, reps: int, durations: Sequence[float] = DURATIONS
) -> None:
    """Tune on spirals of each duration; evaluate every tuned front on every duration."""
    spirals = {d: TrajectorySpec(kind=TrajectoryKind.spiral, duration=d) for d in durations}
    matrix: dict[tuple[float, float], list[list[Point]]] = {}
    errors: dict[tuple[float, float], list[float]] = {}

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
    for (_, tuned), (record, on) in done.items():
        members = record.front
        for used in durations:
            points = on[used]
            matrix.setdefault((tuned, used), []).append(points)
            # The most accurate controller (on its own trajectory) and its error on `used`.
            most_accurate = min(range(len(members)), key=lambda i: members[i].f_acc)
            errors.setdefault((tuned, used), []).append(points[most_accurate][0])
    # One normalised space per trajectory evaluated on: fronts on one spiral compare.
    normalisations = {
        u: experiment.normalisation([p for t in durations for p in matrix[(t, u)]])
        for u in durations
    }
    experiment.write_normalisation({f"on {u:g} s": n for u, n in normalisations.items()})
    hypervolumes = {
        (t, u): [normalisations[u].hypervolume(p) for p in matrix[(t, u)]]
        for t in durations
        for u in durations
    }
    hv = {key: statistics.median(value) for key, value in hypervolumes.items()}
    error = {key: statistics.median(value) for key, value in errors.items()}
    rows = [
        {
            "tuned_on_s": t,
            "evaluated_on_s": u,
            "median_hypervolume": hv[(t, u)],
            "median_error_of_most_accurate_m": error[(t, u)],
        }
        for t in durations
        for u in durations
    ]
    experiment.write_results(rows)
    figure(experiment.out / FIGURE, durations, hv, error, matrix)
    ordered = sorted(durations)
    own = {d: error[(d, d)] for d in durations}
    # Accuracy on its own spiral, each duration against the next shorter one (lower is better).
    falls = step_comparisons({d: errors[(d, d)] for d in durations})
    stats_rows = [
        stats.StatsRow(NAME, f"{slow:g} s vs {fast:g} s, own spiral", "error_m", result)
        for (fast, slow), result in falls.items()
    ]
    transfers = {
        (t, u): (
            stats.compare(errors[(t, u)], errors[(u, u)]),
            stats.compare(hypervolumes[(t, u)], hypervolumes[(u, u)]),
        )
        for u in durations
        for t in durations
        if t != u
    }
    for (t, u), (err, hyper) in transfers.items():
        comparison = f"tuned on {t:g} s vs tuned on {u:g} s, on {u:g} s"
        stats_rows += [
            stats.StatsRow(NAME, comparison, "error_m", err),
            stats.StatsRow(NAME, comparison, "hypervolume", hyper),
        ]
    experiment.write_stats(stats_rows)
    on_own = ", ".join(f"{own[d] * 1000:.2f} mm at {d:g} s" for d in ordered)
    lines = [
        f"- {slow:g} s against {fast:g} s, own spiral: "
        + stats.decide(result, f"{slow:g} s", f"{fast:g} s", higher_is_better=False)
        for (fast, slow), result in falls.items()
    ]
    finding = levels_off(
        falls, reps, "accuracy", "duration", "{:g} s".format, higher_is_better=False
    ).text
    verdict_lines = [
        f"The most accurate controller's error on its own spiral: {on_own}. {finding} (The "
        "paper: it falls, and levels off near 5 s.)",
        "",
        *lines,
    ]
    if transfers:
        worse = sum(stats.better(err, False) == "b" for err, _ in transfers.values())
        undecidable = sum(not stats.decidable(err) for err, _ in transfers.values())
        cost = statistics.median(error[(t, u)] / own[u] - 1 for t, u in transfers)
        verdict_lines += [
            "",
            f"Run at another speed, the most accurate controller changes its error by a median of "
            f"{cost:+.0%} against the one tuned for that speed; it is significantly worse in "
            f"{worse} of {len(transfers)} cases"
            + (f" ({undecidable} cannot be decided with {reps} repetitions)" if undecidable else "")
            + " (the paper: moving a controller to another speed costs little).",
        ]
    experiment.write_report(
        "Trajectory speed",
        base,
        reps,
        table(durations, error),
        "\n".join(verdict_lines),
        [FIGURE],
        {f"on {u:g} s": n for u, n in normalisations.items()},
        durations=durations,
    )


def table(durations: Sequence[float], error: Mapping[tuple[float, float], float]) -> list[str]:
    """The most accurate controller's error, tuned-on duration against evaluated-on duration."""
    return markdown_table(
        ["tuned on", *(f"on {d:g} s" for d in durations)],
        ([f"{t:g} s", *(f"{error[(t, u)] * 1000:.2f} mm" for u in durations)] for t in durations),
    )


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
    hypervolume: Mapping[tuple[float, float], float],
    error: Mapping[tuple[float, float], float],
    fronts: Mapping[tuple[float, float], list[list[Point]]] | None = None,
) -> None:
    """Two matrices, tuned-on duration against evaluated-on duration: the median hypervolume and
    the most accurate controller's error; and, if `fronts` ((tuned on, evaluated on) → one
    front per repetition), a row of median attainment surfaces, one panel per spiral evaluated
    on."""
    columns = max(2, len(durations)) if fronts else 2
    canvas = new_figure((5 * columns, 9 if fronts else 4.5))
    panels = canvas.subplots(2 if fronts else 1, columns, squeeze=False)
    left, right = panels[0][0], panels[0][1]
    for axes, values, title, fmt in (
        (left, hypervolume, "median hypervolume", "{:.3f}"),
        (
            right,
            {k: v * 1000 for k, v in error.items()},
            "most accurate controller's error (mm)",
            "{:.2f}",
        ),
    ):
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
    for axes in panels[0][2:]:
        axes.set_axis_off()
    if fronts:
        for column, used in enumerate(durations):
            attainment_panel(
                panels[1][column],
                {f"tuned on {t:g} s": fronts[(t, used)] for t in durations},
                f"fronts on the {used:g} s spiral",
            )
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
