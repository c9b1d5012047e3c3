"""Figures of a run, drawn from plain data, written as PNGs (each experiment draws its own with
`new_figure` and `save_png`: analytic.experiments).

Edge code with no state: every function takes plain data and a path chosen by the caller, so it
can be called on a finished run or after every generation of one in progress. Each PNG appears
whole or not at all, so a reader refreshing mid-run never sees half a file.

Figures are drawn on a bare `matplotlib.figure.Figure` with the Agg canvas, never through
pyplot: no global figure registry to leak, no GUI backend, safe beside the run loop's threads.
"""

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gainfarm.analytic.tuning.declared import axis_label, declarations, shown_unit
from gainfarm.analytic.tuning.records import Baseline, FrontMember, HistoryRow, sorted_front
from gainfarm.analytic.view.export import Pick
from gainfarm.cli.words import counted
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES
from gainfarm.schemas.objectives import Objective

DPI = 120
FIGURE_SIZE = (7.0, 5.0)  # inches: 840 × 600 px at DPI


def new_figure(size: tuple[float, float] = FIGURE_SIZE) -> Figure:
    figure = Figure(figsize=size, dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)  # Agg explicitly: no backend lookup, no display needed
    return figure


def save_png(figure: Figure, path: Path) -> None:
    """Render in memory first, so a failed render writes nothing and the write is one rename."""
    buffer = io.BytesIO()
    # No Software/date metadata: the same figure gives the same bytes on any matplotlib.
    figure.savefig(buffer, format="png", dpi=DPI, metadata={"Software": None})
    write_atomically(Path(path), buffer.getvalue())


# How each pick is marked on a run's Pareto figure (analytic.tuning.picks names them): largest
# first and drawn first, so that picks of one member show as markers one inside the other.
PICK_STYLES = {
    "recommended": ("*", 420, "gold", "recommended (use this)"),
    "closest": ("P", 300, "darkorange", "closest to dominating the defaults"),
    "knee": ("D", 170, "tab:purple", "knee of the whole front"),
    "accurate": ("^", 90, "tab:blue", "most accurate"),
    "smooth": ("s", 30, "tab:green", "smoothest"),
}
MARGIN = 0.08  # of the view's span, either side
LOG_MARGIN = 0.15  # decades of f_t, at least, either side


def plot_pareto(
    path: Path,
    front: Sequence[FrontMember],
    evaluated: Sequence[tuple[float, ...]] = (),
    title: str = "",
    picks: Sequence[Pick] = (),
    baseline: Baseline | None = None,
    infeasible: int = 0,
    names: Sequence[str] = DEFAULT_OBJECTIVES,
) -> None:
    """The figure of `pareto_figure`, as a PNG at `path`."""
    figure = pareto_figure(front, evaluated, title, picks, baseline, infeasible, names)
    save_png(figure, path)


def _span(low: float, high: float, least: float) -> tuple[float, float]:
    """[low, high] widened by MARGIN of its span either side, and by at least `least`."""
    margin = max(MARGIN * (high - low), least)
    return low - margin, high + margin


# The view pareto.png frames around its points, an axis at a time (the dashboard's front is
# framed so too): f_acc widened by a margin, never below 0 when every point is above it (no error
# below 0 mm); f_t (> 0, on a log axis) by a margin in decades.
def x_view(x: Sequence[float]) -> tuple[float, float]:
    low, high = _span(min(x), max(x), 0.05 * max(x) or 1.0)
    return max(low, 0.0) if min(x) > 0 else low, high


def log_view(y: Sequence[float]) -> tuple[float, float]:
    low, high = _span(math.log10(min(y)), math.log10(max(y)), LOG_MARGIN)
    return 10**low, 10**high


Point = tuple[float, float]


@dataclass(frozen=True)
class Axes2:
    """The two objectives a Pareto figure draws (a run's first two), and how: each value as
    told turned to its own sense and shown unit (f_acc in mm); the second on a log axis when
    any of its values is positive, points at or below 0 then drawn on the axis floor."""

    objectives: tuple[Objective, Objective]

    def own(self, points: Sequence[Sequence[float]]) -> list[Point]:
        """Told points in their own sense and shown units."""
        x, y = self.objectives
        (_, fx), (_, fy) = shown_unit(x), shown_unit(y)
        return [(x.minimised(float(p[0])) * fx, y.minimised(float(p[1])) * fy) for p in points]


def _finite(points: Sequence[Point]) -> list[Point]:
    return [(x, y) for x, y in points if math.isfinite(x) and math.isfinite(y)]


@dataclass
class _Scale:
    log: bool
    floor: float

    def drawable(self, points: Sequence[Point]) -> tuple[list[float], list[float]]:
        kept = _finite(points)
        return [x for x, _ in kept], [max(y, self.floor) if self.log else y for _, y in kept]


def pareto_figure(
    front: Sequence[FrontMember],
    evaluated: Sequence[tuple[float, ...]] = (),
    title: str = "",
    picks: Sequence[Pick] = (),
    baseline: Baseline | None = None,
    infeasible: int = 0,
    names: Sequence[str] = DEFAULT_OBJECTIVES,
) -> Figure:
    """Every evaluation in light grey with the front on top (`infeasible`: those left out of
    `evaluated` for breaking a safety limit, counted in the legend); the `picks` (recommended
    or closest, knee, most accurate, smoothest) marked and labelled with their front.csv rows,
    and the default gains' point (`baseline`) as a black cross, unless it diverged (a penalty,
    named in a note). The axes are the run's objectives (`names`), labelled with their names,
    descriptions and units; `evaluated` and the members' objectives are as told, drawn in their
    own sense. A run of more than two objectives would be drawn on its first two, said in a note.

    The view is the front's: its measured members (not the penalty points of diverged ones),
    the picks and the default gains, with a margin. What else was evaluated (a chattering or a
    soft candidate far off) would squash the front into a corner, so it is left out of the view
    and counted in a note. f_acc is drawn in mm; the second objective (f_t) on a log axis, since
    a front's f_t spans orders of magnitude. A log axis cannot show a value ≤ 0, so such points
    are drawn on the axis floor, a decade below the smallest positive value, and counted in a
    note; points with a non-finite objective are left out and counted too. The front is joined
    by a step line sorted by the first objective: the boundary of what it dominates, so a gap in
    the front shows as a long flat step. The legend sits below the axes, where it covers no
    point.
    """
    first, second = declarations(names[:2])
    axes2 = Axes2((first, second))
    cloud = axes2.own(evaluated)
    ordered = sorted_front(front)
    members = axes2.own([member.objectives for member in ordered])
    told_baseline = [baseline.objectives] if baseline is not None and not baseline.diverged else []
    reference = axes2.own(told_baseline)
    drawn = _finite(cloud + members + reference)
    positive = [y for _, y in drawn if y > 0]
    scale = _Scale(bool(positive), min(positive) / 10 if positive else 0.0)
    notes = _notes(len(cloud) + len(members) + len(reference) - len(drawn), drawn, scale, second)
    if baseline is not None and baseline.diverged:
        notes.append("default gains diverged: their penalty point is not drawn")
    if len(names) > 2:
        notes.append(f"the first two of {len(names)} objectives drawn")
    measured = axes2.own([m.objectives for m in ordered if not m.diverged])
    view_x, view_y = scale.drawable(
        (measured or members) + reference + axes2.own([p.member.objectives for p in picks])
    )
    figure = new_figure()
    axes = figure.add_subplot()
    cloud_x, cloud_y = scale.drawable(cloud)
    _draw_points(axes, scale, cloud, members, reference, infeasible, axes2)
    _draw_picks(axes, scale, picks, axes2)
    if scale.log:
        axes.set_yscale("log")
    if view_x:
        _frame(axes, scale, view_x, view_y)
        (x_low, x_high), (y_low, y_high) = axes.get_xlim(), axes.get_ylim()
        outside = sum(
            1
            for x, y in zip(cloud_x, cloud_y, strict=True)
            if not (x_low <= x <= x_high and y_low <= y <= y_high)
        )
        if outside:
            notes.append(f"{counted(outside, 'evaluated point')} outside the view")
    axes.set_xlabel(axis_label(first))
    axes.set_ylabel(axis_label(second))
    axes.set_title(title or "Pareto front", fontsize=10)
    axes.grid(True, which="major", alpha=0.3)
    if axes.get_legend_handles_labels()[0]:
        figure.legend(loc="outside lower center", ncols=2, fontsize=8)
    if notes:  # bottom left: the ideal corner, where no point of the front can be
        axes.text(
            0.01,
            0.01,
            "\n".join(notes),
            transform=axes.transAxes,
            va="bottom",
            fontsize=8,
            color="0.3",
        )
    if not drawn:
        axes.text(0.5, 0.5, "no evaluations yet", transform=axes.transAxes, ha="center")
    return figure


def _notes(dropped: int, drawn: Sequence[Point], scale: _Scale, second: Objective) -> list[str]:
    """What the figure leaves out or moves: points with a non-finite objective, points at or
    below 0 on the log axis."""
    notes = []
    if dropped:
        notes.append(f"{counted(dropped, 'point')} with a non-finite objective not drawn")
    if scale.log and (clipped := sum(1 for _, y in drawn if y <= 0)):
        notes.append(f"{counted(clipped, 'point')} with {second.name} ≤ 0 drawn at the axis floor")
    return notes


def _point_text(axes2: Axes2, point: Point) -> str:
    """A point's label: "12.34 mm, 0.567" (the second objective's unit left to its axis)."""
    unit = shown_unit(axes2.objectives[0])[0]
    return f"{point[0]:.2f} {unit}".strip() + f", {point[1]:.3g}"


def _draw_points(
    axes: Any,
    scale: _Scale,
    cloud: Sequence[Point],
    members: Sequence[Point],
    reference: Sequence[Point],
    infeasible: int,
    axes2: Axes2,
) -> None:
    """The cloud of evaluations, the front (points and step line) and the default gains."""
    cloud_x, cloud_y = scale.drawable(cloud)
    front_x, front_y = scale.drawable(members)
    # The cloud is what the caller passes: a run's candidates within its limits; those that
    # broke one are counted here, so the legend's count adds up to the run's evaluations.
    beyond = f"; {infeasible} beyond a limit, not drawn" if infeasible else ""
    axes.scatter(
        cloud_x, cloud_y, s=12, color="0.75", label=f"evaluated ({len(cloud)}{beyond})", zorder=1
    )
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
    if reference:
        x, y = scale.drawable(reference)
        axes.scatter(
            x,
            y,
            marker="X",
            s=110,
            color="black",
            label=f"default gains: {_point_text(axes2, reference[0])}",
            zorder=4,
        )


def _draw_picks(axes: Any, scale: _Scale, picks: Sequence[Pick], axes2: Axes2) -> None:
    """Each pick marked in its style, and one "row N" label a member, however many picks it is."""
    rows: dict[int, list[float]] = {}
    for order, chosen in enumerate(sorted(picks, key=lambda p: list(PICK_STYLES).index(p.name))):
        marker, size, colour, name = PICK_STYLES[chosen.name]
        point = axes2.own([chosen.member.objectives])
        x, y = scale.drawable(point)
        axes.scatter(
            x,
            y,
            marker=marker,
            s=size,
            color=colour,
            edgecolor="black",
            linewidth=0.8,
            label=f"{name}: row {chosen.row}, {_point_text(axes2, point[0])}",
            zorder=5 + order,
        )
        if x:
            rows.setdefault(chosen.row, [x[0], y[0]])
    for row, (x, y) in rows.items():
        axes.annotate(
            f"row {row}", (x, y), xytext=(9, 7), textcoords="offset points", fontsize=8, zorder=10
        )


def _frame(axes: Any, scale: _Scale, view_x: Sequence[float], view_y: Sequence[float]) -> None:
    """The view around the front, the picks and the default gains, with a margin."""
    axes.set_xlim(*x_view(view_x))
    if scale.log:
        axes.set_ylim(*log_view(view_y))
    else:
        axes.set_ylim(*_span(min(view_y), max(view_y), 0.05 * max(view_y) or 1.0))


def plot_hypervolume(
    path: Path,
    history: Sequence[HistoryRow],
    title: str = "",
    baseline: float | None = None,
) -> None:
    """`hypervolume_figure` as a PNG at `path`."""
    save_png(hypervolume_figure(history, title, baseline), path)


# What the hypervolume's axis is: the share of the normalised objective space a front dominates
# (analytic/tuning/evolution.py's REFERENCE_POINT).
HYPERVOLUME_LABEL = "hypervolume (normalised: 0 to 1)"
HYPERVOLUME_NOTE = (
    "normalised: f_acc linear from 0 to 0.2 m, f_t logarithmic from 0.01 to 10⁴ (N·m)²; "
    "1 dominates all of it"
)


def hypervolume_note(names: Sequence[str] = DEFAULT_OBJECTIVES) -> str:
    """How the hypervolume is normalised, naming the run's objectives (the same numbers: the
    first objective linear, the second logarithmic, analytic/tuning/evolution.py's normalise)."""
    if tuple(names) == DEFAULT_OBJECTIVES:
        return HYPERVOLUME_NOTE
    return (
        f"normalised: {names[0]} linear from 0 to 0.2, {names[1]} logarithmic from 0.01 to 10⁴, "
        "each in its unit; 1 dominates all of it"
    )


def hypervolume_figure(
    history: Sequence[HistoryRow], title: str = "", baseline: float | None = None
) -> Figure:
    """Hypervolume against evaluations spent, one marker per generation; `baseline`: the
    hypervolume the default gains alone dominate, drawn as a level the front should pass.

    Evaluations rather than generations on the x axis: they are what a run costs, and they make
    runs with different population sizes comparable.
    """
    figure = new_figure()
    axes = figure.add_subplot()
    axes.plot(
        [row.evaluations for row in history],
        [row.hypervolume for row in history],
        marker="o",
        markersize=4,
        color="tab:blue",
        label="the run's front",
    )
    if baseline is not None:
        axes.axhline(baseline, color="tab:gray", linestyle="--", label="the default gains alone")
        axes.legend(loc="best")
    axes.set_xlabel("evaluations")
    axes.set_ylabel(HYPERVOLUME_LABEL)
    axes.set_title(title or "Hypervolume")
    names = history[0].names if history else DEFAULT_OBJECTIVES
    figure.supxlabel(hypervolume_note(names), fontsize=7, color="dimgray")  # laid out with the axes
    axes.grid(True, alpha=0.3)
    if not history:
        axes.text(0.5, 0.5, "no generations yet", transform=axes.transAxes, ha="center")
    return figure
