"""Figures of a run and of the paper's experiments, drawn from plain data, written as PNGs.

Edge code with no state: every function takes plain data and a path chosen by the caller, so it
can be called on a finished run or after every generation of one in progress. Each PNG appears
whole or not at all, so a reader refreshing mid-run never sees half a file.

Figures are drawn on a bare `matplotlib.figure.Figure` with the Agg canvas, never through
pyplot: no global figure registry to leak, no GUI backend, safe beside the run loop's threads.
"""

import io
import math
from collections.abc import Sequence
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gainfarm.analytic.tuning.records import Baseline, FrontMember, HistoryRow, sorted_front
from gainfarm.analytic.view.export import Pick
from gainfarm.schemas.files import write_atomically

DPI = 120
FIGURE_SIZE = (7.0, 5.0)  # inches: 840 × 600 px at DPI


def _new_figure(size: tuple[float, float] = FIGURE_SIZE) -> Figure:
    figure = Figure(figsize=size, dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)  # Agg explicitly: no backend lookup, no display needed
    return figure


def save_png(figure: Figure, path: Path) -> None:
    """Render in memory first, so a failed render writes nothing and the write is one rename."""
    buffer = io.BytesIO()
    # No Software/date metadata: the same figure gives the same bytes on any matplotlib.
    figure.savefig(buffer, format="png", dpi=DPI, metadata={"Software": None})
    write_atomically(Path(path), buffer.getvalue())


# How each pick is marked on a run's Pareto figure (analytic.export.picks names them).
PICK_STYLES = {
    "knee": ("*", 260, "gold", "knee (the controller to use)"),
    "accurate": ("^", 110, "tab:blue", "most accurate"),
    "smooth": ("s", 90, "tab:green", "smoothest"),
}


def plot_pareto(
    path: Path,
    front: Sequence[FrontMember],
    evaluated: Sequence[tuple[float, float]] = (),
    title: str = "",
    picks: Sequence[Pick] = (),
    baseline: Baseline | None = None,
) -> None:
    """The figure of `pareto_figure`, as a PNG at `path`."""
    save_png(pareto_figure(front, evaluated, title, picks, baseline), path)


def pareto_figure(
    front: Sequence[FrontMember],
    evaluated: Sequence[tuple[float, float]] = (),
    title: str = "",
    picks: Sequence[Pick] = (),
    baseline: Baseline | None = None,
) -> Figure:
    """Every evaluation (f_acc, f_t) in light grey with the front on top; the `picks` (knee,
    most accurate, smoothest) marked and labelled with their front.csv rows, and the default
    gains' point (`baseline`) as a black cross, unless it diverged (a penalty, named in a note).

    f_acc is drawn in mm; f_t on a log axis, since a run's f_t spans orders of magnitude (a
    diverged episode is charged the worst torque change for every tick it missed). A log axis
    cannot show f_t ≤ 0, so such points are drawn on the axis floor, a decade below the smallest
    positive value, and counted in a note; points with a non-finite objective are left out and
    counted too. The front is joined by a step line sorted by f_acc: the boundary of what it
    dominates, so a gap in the front shows as a long flat step.
    """
    cloud = [(float(f_acc), float(f_t)) for f_acc, f_t in evaluated]
    members = [(member.f_acc, member.f_t) for member in sorted_front(front)]
    reference = [baseline.objectives] if baseline is not None and not baseline.diverged else []

    finite = [
        (f_acc, f_t)
        for f_acc, f_t in cloud + members + reference
        if math.isfinite(f_acc) and math.isfinite(f_t)
    ]
    positive = [f_t for _, f_t in finite if f_t > 0]
    log_scale = bool(positive)
    floor = min(positive) / 10 if positive else 0.0
    notes = []
    if dropped := len(cloud) + len(members) + len(reference) - len(finite):
        notes.append(f"{dropped} point(s) with a non-finite objective not drawn")
    if log_scale and (clipped := sum(1 for _, f_t in finite if f_t <= 0)):
        notes.append(f"{clipped} point(s) with f_t ≤ 0 drawn at the axis floor")
    if baseline is not None and baseline.diverged:
        notes.append("default gains diverged: their penalty point is not drawn")

    def drawable(points: list[tuple[float, float]]) -> tuple[list[float], list[float]]:
        kept = [(x, y) for x, y in points if math.isfinite(x) and math.isfinite(y)]
        return (
            [x * 1000.0 for x, _ in kept],
            [max(y, floor) if log_scale else y for _, y in kept],
        )

    figure = _new_figure()
    axes = figure.add_subplot()
    cloud_x, cloud_y = drawable(cloud)
    front_x, front_y = drawable(members)
    axes.scatter(cloud_x, cloud_y, s=12, color="0.75", label=f"evaluated ({len(cloud)})", zorder=1)
    if front_x:
        axes.step(front_x, front_y, where="post", color="tab:red", linewidth=1.2, zorder=2)
    axes.scatter(
        front_x,
        front_y,
        s=28,
        color="tab:red",
        edgecolor="black",
        linewidth=0.5,
        label=f"Pareto front ({len(members)})",
        zorder=3,
    )
    for chosen in picks:
        marker, size, colour, name = PICK_STYLES[chosen.name]
        x, y = drawable([chosen.member.objectives])
        axes.scatter(
            x,
            y,
            marker=marker,
            s=size,
            color=colour,
            edgecolor="black",
            linewidth=0.8,
            label=f"{name}: row {chosen.row}, {chosen.member.f_acc * 1000:.2f} mm, "
            f"{chosen.member.f_t:.3g}",
            zorder=5,
        )
    if reference:
        x, y = drawable(reference)
        axes.scatter(
            x,
            y,
            marker="X",
            s=110,
            color="black",
            label=f"default gains: {reference[0][0] * 1000:.2f} mm, {reference[0][1]:.3g}",
            zorder=4,
        )
    if log_scale:
        axes.set_yscale("log")
    axes.set_xlabel("f_acc: mean end-effector error (mm)")
    axes.set_ylabel("f_t: mean squared torque change per tick ((N·m)²)")
    axes.set_title(title or "Pareto front", fontsize=10)
    axes.grid(True, which="major", alpha=0.3)
    axes.legend(loc="upper right", fontsize=8)
    if notes:  # top left: the front lies low and the legend sits top right
        axes.text(
            0.01,
            0.99,
            "\n".join(notes),
            transform=axes.transAxes,
            va="top",
            fontsize=8,
            color="0.3",
        )
    if not finite:
        axes.text(0.5, 0.5, "no evaluations yet", transform=axes.transAxes, ha="center")
    return figure


def plot_hypervolume(path: Path, history: Sequence[HistoryRow], title: str = "") -> None:
    """Hypervolume against evaluations spent, one marker per generation, as a PNG at `path`.

    Evaluations rather than generations on the x axis: they are what a run costs, and they make
    runs with different population sizes comparable.
    """
    figure = _new_figure()
    axes = figure.add_subplot()
    axes.plot(
        [row.evaluations for row in history],
        [row.hypervolume for row in history],
        marker="o",
        markersize=4,
        color="tab:blue",
    )
    axes.set_xlabel("evaluations")
    axes.set_ylabel("hypervolume")
    axes.set_title(title or "Hypervolume")
    axes.grid(True, alpha=0.3)
    if not history:
        axes.text(0.5, 0.5, "no generations yet", transform=axes.transAxes, ha="center")
    save_png(figure, path)


# --- the experiments' figures --------------------------------------------------------------------


Point = tuple[float, float]


def median_attainment(point_sets: Sequence[Sequence[Point]]) -> list[Point] | None:
    """The median (50 %) empirical attainment surface of `point_sets` (one set per repetition),
    sorted by f_acc; penalty points (f_acc ≥ 1 m, non-finite) left out. None if moocore (the
    EAF's library) is not installed."""
    try:
        import moocore
    except ImportError:
        return None
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


def _attainment_panel(
    axes: object, conditions: dict[str, Sequence[Sequence[Point]]], title: str
) -> None:
    """Median attainment surfaces, one step line per condition (rep 0's front without moocore),
    f_acc in mm against f_t on a log axis."""
    drawn = False
    for label, point_sets in conditions.items():
        surface = median_attainment(point_sets)
        what = "median attainment"
        if surface is None:
            surface = sorted(p for p in point_sets[0] if p[0] < 1.0) if point_sets else []
            what = "rep 0 front"
        if not surface:
            continue
        drawn = True
        axes.step(  # type: ignore[attr-defined]
            [p[0] * 1000 for p in surface],
            [max(p[1], 1e-12) for p in surface],
            where="post",
            marker=".",
            label=f"{label} ({what})",
        )
    axes.set(xlabel="f_acc (mm)", ylabel="f_t ((N·m)²)", title=title)  # type: ignore[attr-defined]
    if drawn:
        axes.set_yscale("log")  # type: ignore[attr-defined]
        axes.legend(fontsize=7)  # type: ignore[attr-defined]


def plot_popsize(
    path: Path,
    hypervolumes: dict[int, list[float]],
    evaluations: dict[int, list[int]],
    fronts: dict[int, list[list[Point]]] | None = None,
) -> None:
    """Box plots per population size: final hypervolume, and evaluations to stop; and each
    size's median attainment surface, if `fronts` (per size, one front per repetition)."""
    figure = _new_figure((15 if fronts else 10, 4))
    panels = figure.subplots(1, 3 if fronts else 2)
    left, right = panels[0], panels[1]
    labels = [str(size) for size in hypervolumes]
    left.boxplot(list(hypervolumes.values()), tick_labels=labels)
    left.set(
        xlabel="population size", ylabel="hypervolume (study normalised)", title="final hypervolume"
    )
    right.boxplot([evaluations[size] for size in hypervolumes], tick_labels=labels)
    right.set(xlabel="population size", ylabel="evaluations", title="evaluations to stop")
    if fronts:
        _attainment_panel(
            panels[2], {f"pop {s}": sets for s, sets in fronts.items()}, "fronts per size"
        )
    save_png(figure, path)


def plot_generic_vs_specific(
    path: Path,
    hypervolumes: dict[str, dict[str, list[float]]],
    fronts: dict[str, dict[str, list[list[Point]]]],
) -> None:
    """Per held-out test trajectory (a column each): hypervolume box plots per kind of
    controller on top, their median attainment surfaces on that trajectory below."""
    kinds = list(hypervolumes)
    figure = _new_figure((4.5 * max(1, len(kinds)), 8))
    panels = figure.subplots(2, max(1, len(kinds)), squeeze=False)
    for column, kind in enumerate(kinds):
        top, bottom = panels[0][column], panels[1][column]
        top.boxplot(list(hypervolumes[kind].values()), tick_labels=list(hypervolumes[kind]))
        top.set(ylabel=f"hypervolume on the {kind}", title=f"judged on the {kind} (held out)")
        _attainment_panel(bottom, fronts.get(kind, {}), f"fronts on the {kind}")
    save_png(figure, path)


def text_colour(background: Sequence[float]) -> str:
    """Black or white, whichever reads better on `background` (RGB(A), 0-1): the one of
    higher WCAG contrast, from the background's relative luminance."""
    linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in background[:3]]
    luminance = 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]
    # Contrast with black (L + 0.05) / 0.05 against with white 1.05 / (L + 0.05).
    return "black" if (luminance + 0.05) ** 2 > 0.05 * 1.05 else "white"


def plot_speed(
    path: Path,
    durations: Sequence[float],
    hypervolume: dict[tuple[float, float], float],
    error: dict[tuple[float, float], float],
    fronts: dict[tuple[float, float], list[list[Point]]] | None = None,
) -> None:
    """Two matrices, tuned-on duration against evaluated-on duration: the median hypervolume and
    the most accurate controller's error; and, if `fronts` ((tuned on, evaluated on) → one
    front per repetition), a row of median attainment surfaces, one panel per spiral evaluated
    on."""
    columns = max(2, len(durations)) if fronts else 2
    figure = _new_figure((5 * columns, 9 if fronts else 4.5))
    panels = figure.subplots(2 if fronts else 1, columns, squeeze=False)
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
        figure.colorbar(image, ax=axes)
    for axes in panels[0][2:]:
        axes.set_axis_off()
    if fronts:
        for column, used in enumerate(durations):
            _attainment_panel(
                panels[1][column],
                {f"tuned on {t:g} s": fronts[(t, used)] for t in durations},
                f"fronts on the {used:g} s spiral",
            )
        for axes in panels[1][len(durations) :]:
            axes.set_axis_off()
    save_png(figure, path)


def plot_algorithms(
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
    figure = _new_figure((13, 5))
    left, right = figure.subplots(1, 2)
    _attainment_panel(left, fronts, "median attainment per condition")
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
        ylabel="median hypervolume (study normalised)",
        title="hypervolume against evaluations",
    )
    right.grid(True, alpha=0.3)
    if curves or levels:
        right.legend(fontsize=7)
    save_png(figure, path)


def plot_dataset_value(
    path: Path, nmse: dict[str, dict[str, list[float]]], reference: float | None = None
) -> None:
    """The dataset-value experiment: test nMSE per condition, one panel per model; a point per
    repetition (jittered sideways so equal values stay visible) and a bar at the mean. A dashed
    line at `reference` (the untrained rigid prior's nMSE), if given. Log scale when the values
    span more than a decade, as random gains' data can be far worse than the rest."""
    models = list(nmse)
    figure = _new_figure((4.0 * max(1, len(models)), 4.5))
    panels = figure.subplots(1, max(1, len(models)), sharey=True, squeeze=False)[0]
    values = [v for per_model in nmse.values() for vs in per_model.values() for v in vs]
    finite = [v for v in values if math.isfinite(v) and v > 0]
    logarithmic = bool(finite) and max(finite) > 10 * min(finite)
    for axes, model in zip(panels, models, strict=False):
        conditions = list(nmse[model])
        for index, condition in enumerate(conditions):
            points = [v for v in nmse[model][condition] if math.isfinite(v)]
            if not points:
                continue
            offsets = [
                0.15 * (k / (len(points) - 1) - 0.5) if len(points) > 1 else 0.0
                for k in range(len(points))
            ]
            axes.scatter(
                [index + o for o in offsets], points, s=14, color="tab:blue", alpha=0.6, zorder=2
            )
            mean = sum(points) / len(points)
            axes.hlines(mean, index - 0.3, index + 0.3, color="black", linewidth=2, zorder=3)
        if reference is not None and math.isfinite(reference):
            axes.axhline(reference, color="grey", linestyle="--", linewidth=1, label="rigid prior")
            axes.legend(loc="upper left", fontsize=8)
        axes.set_xticks(range(len(conditions)))
        axes.set_xticklabels(conditions, rotation=45, ha="right", fontsize=8)
        axes.set_title(model)
        axes.grid(True, axis="y", alpha=0.3)
        if logarithmic:
            axes.set_yscale("log")
    panels[0].set_ylabel("test nMSE (mean A1-A6)")
    save_png(figure, path)
