"""A run directory's numbers as a person reads them: two figures, a short report and the CSVs.

This is edge code and holds no state: every function takes plain data and a path chosen by the
caller, so it can be called on a finished run or after every generation of one in progress. Each
file appears whole or not at all (through `schemas.files.write_atomically`): a reader refreshing
the report mid-run, or a crash mid-write, never sees a half-written PNG or CSV.

The CSV layout lives here and only here, so the writer of a run and every reader of it agree.
Floats are written repr-exact (shortest round-tripping form), so reading a file back gives the
very same numbers and two identical runs give byte-identical files.

Figures are drawn on a bare `matplotlib.figure.Figure` with the Agg canvas, never through
pyplot: no global figure registry to leak, no GUI backend, safe beside the run loop's threads.
"""

import csv
import io
import math
import operator
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from schemas.files import write_atomically

JOINTS = 7
DPI = 120
FIGURE_SIZE = (7.0, 5.0)  # inches: 840 × 600 px at DPI

# The names a run directory uses; the report links to the figures by these relative names.
PARETO_PNG = "pareto.png"
HYPERVOLUME_PNG = "hypervolume.png"
FRONT_CSV = "front.csv"
HISTORY_CSV = "history.csv"
REPORT_MD = "report.md"

HISTORY_FIELDS = (
    "generation",
    "evaluations",
    "hypervolume",
    "best_f_acc",
    "best_f_t",
    "wall_seconds",
)
FRONT_FIELDS = (
    *(f"kp{joint}" for joint in range(1, JOINTS + 1)),
    *(f"kd{joint}" for joint in range(1, JOINTS + 1)),
    "f_acc",
    "f_t",
)


@dataclass(frozen=True)
class HistoryRow:
    """One generation of a run, one line of history.csv.

    `evaluations` and `wall_seconds` are cumulative since the start of the run; `best_f_acc` (m)
    and `best_f_t` ((N·m)²) are the best value of each objective found so far.
    """

    generation: int
    evaluations: int
    hypervolume: float
    best_f_acc: float
    best_f_t: float
    wall_seconds: float

    def __post_init__(self) -> None:
        # Normalise numpy scalars to Python numbers: repr(np.float64(1.0)) is "np.float64(1.0)",
        # which would corrupt the CSV, and equality with rows read back should just work.
        # operator.index refuses a float generation rather than silently truncating it.
        object.__setattr__(self, "generation", operator.index(self.generation))
        object.__setattr__(self, "evaluations", operator.index(self.evaluations))
        for name in ("hypervolume", "best_f_acc", "best_f_t", "wall_seconds"):
            object.__setattr__(self, name, float(getattr(self, name)))


@dataclass(frozen=True)
class FrontMember:
    """One non-dominated controller, one line of front.csv: its 14 gains and its two scores.

    f_acc is in metres, f_t in (N·m)². Gains may be given as any sequence (a numpy row, say);
    they are stored as tuples of Python floats so members compare and hash by value.
    """

    kp: tuple[float, ...]
    kd: tuple[float, ...]
    f_acc: float
    f_t: float

    def __post_init__(self) -> None:
        for name in ("kp", "kd"):
            gains = tuple(float(gain) for gain in getattr(self, name))
            if len(gains) != JOINTS:
                raise ValueError(f"{name} needs {JOINTS} gains, got {len(gains)}")
            object.__setattr__(self, name, gains)
        object.__setattr__(self, "f_acc", float(self.f_acc))
        object.__setattr__(self, "f_t", float(self.f_t))


# --- CSV ---------------------------------------------------------------------------------------


def _exact(value: float) -> str:
    """The shortest text that reads back as exactly `value` (float's repr), numpy-proof."""
    return repr(float(value))


def _nan_last(value: float) -> tuple[bool, float]:
    """A sort key that puts NaN after every number instead of scrambling the order."""
    return (math.isnan(value), value)


def _front_order(member: FrontMember) -> tuple:
    """f_acc, then f_t, then the gains: a total order, so equal fronts give equal files."""
    return (_nan_last(member.f_acc), _nan_last(member.f_t), member.kp, member.kd)


def sorted_front(front: Iterable[FrontMember]) -> list[FrontMember]:
    """The front in the order every output shows it: most accurate first."""
    return sorted(front, key=_front_order)


def _csv_bytes(header: Sequence[str], rows: Iterable[Sequence[str]]) -> bytes:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return buffer.getvalue().encode("utf-8")


def history_csv(history: Sequence[HistoryRow]) -> bytes:
    """history.csv's content, rows in the order given (the order the generations ran)."""
    return _csv_bytes(
        HISTORY_FIELDS,
        (
            (
                str(row.generation),
                str(row.evaluations),
                _exact(row.hypervolume),
                _exact(row.best_f_acc),
                _exact(row.best_f_t),
                _exact(row.wall_seconds),
            )
            for row in history
        ),
    )


def front_csv(front: Sequence[FrontMember]) -> bytes:
    """front.csv's content, sorted by f_acc then f_t so equal fronts give byte-identical files."""
    return _csv_bytes(
        FRONT_FIELDS,
        (
            (
                *map(_exact, member.kp),
                *map(_exact, member.kd),
                _exact(member.f_acc),
                _exact(member.f_t),
            )
            for member in sorted_front(front)
        ),
    )


def _read_rows(path: Path, fields: Sequence[str]) -> list[dict[str, str]]:
    """The rows of a CSV, refusing one whose header is not exactly `fields` (another format)."""
    with Path(path).open(newline="", encoding="utf-8") as stream:
        reader = csv.DictReader(stream)
        if tuple(reader.fieldnames or ()) != tuple(fields):
            raise ValueError(
                f"{path}: expected columns {','.join(fields)}, got {reader.fieldnames}"
            )
        return list(reader)


def read_history(path: Path) -> list[HistoryRow]:
    """history.csv as written by `history_csv`, in file order."""
    return [
        HistoryRow(
            generation=int(row["generation"]),
            evaluations=int(row["evaluations"]),
            hypervolume=float(row["hypervolume"]),
            best_f_acc=float(row["best_f_acc"]),
            best_f_t=float(row["best_f_t"]),
            wall_seconds=float(row["wall_seconds"]),
        )
        for row in _read_rows(path, HISTORY_FIELDS)
    ]


def read_front(path: Path) -> list[FrontMember]:
    """front.csv as written by `front_csv`, in file order (already sorted by f_acc)."""
    return [
        FrontMember(
            kp=tuple(float(row[f"kp{joint}"]) for joint in range(1, JOINTS + 1)),
            kd=tuple(float(row[f"kd{joint}"]) for joint in range(1, JOINTS + 1)),
            f_acc=float(row["f_acc"]),
            f_t=float(row["f_t"]),
        )
        for row in _read_rows(path, FRONT_FIELDS)
    ]


# --- figures -----------------------------------------------------------------------------------


def _new_figure() -> Figure:
    figure = Figure(figsize=FIGURE_SIZE, dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)  # Agg explicitly: no backend lookup, no display needed
    return figure


def save_png(figure: Figure, path: Path) -> None:
    """Render in memory first, so a failed render writes nothing and the write is one rename."""
    buffer = io.BytesIO()
    # No Software/date metadata: the same figure gives the same bytes on any matplotlib.
    figure.savefig(buffer, format="png", dpi=DPI, metadata={"Software": None})
    write_atomically(Path(path), buffer.getvalue())


def plot_pareto(
    path: Path,
    front: Sequence[FrontMember],
    evaluated: Sequence[tuple[float, float]] = (),
    title: str = "",
) -> None:
    """Every evaluation (f_acc, f_t) in light grey with the front on top, as a PNG at `path`.

    f_acc is drawn in mm; f_t on a log axis, since a run's f_t spans orders of magnitude (a
    diverged episode is charged the worst torque change for every tick it missed). A log axis
    cannot show f_t ≤ 0, so such points are drawn on the axis floor, a decade below the smallest
    positive value, and counted in a note; points with a non-finite objective are left out and
    counted too. The front is joined by a step line sorted by f_acc: the boundary of what it
    dominates, so a gap in the front shows as a long flat step.
    """
    cloud = [(float(f_acc), float(f_t)) for f_acc, f_t in evaluated]
    members = [(member.f_acc, member.f_t) for member in sorted_front(front)]

    finite = [
        (f_acc, f_t)
        for f_acc, f_t in cloud + members
        if math.isfinite(f_acc) and math.isfinite(f_t)
    ]
    positive = [f_t for _, f_t in finite if f_t > 0]
    log_scale = bool(positive)
    floor = min(positive) / 10 if positive else 0.0
    notes = []
    if dropped := len(cloud) + len(members) - len(finite):
        notes.append(f"{dropped} point(s) with a non-finite objective not drawn")
    if log_scale and (clipped := sum(1 for _, f_t in finite if f_t <= 0)):
        notes.append(f"{clipped} point(s) with f_t ≤ 0 drawn at the axis floor")

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
    if log_scale:
        axes.set_yscale("log")
    axes.set_xlabel("f_acc: mean end-effector error (mm)")
    axes.set_ylabel("f_t: mean squared torque change per tick ((N·m)²)")
    axes.set_title(title or "Pareto front")
    axes.grid(True, which="major", alpha=0.3)
    axes.legend(loc="upper right")
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
    save_png(figure, path)


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


# --- report ------------------------------------------------------------------------------------


def _duration(seconds: float) -> str:
    """Wall time the way a person says it: 42.0 s, 3 min 07 s, 2 h 05 min."""
    if not math.isfinite(seconds):
        return str(seconds)
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, second = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {second:02d} s"
    hours, minute = divmod(minutes, 60)
    return f"{hours} h {minute:02d} min"


def gains_text(member: FrontMember) -> str:
    """A member's 14 gains on one short line: 'kp 2000 2000 1200 … / kd 20 20 15 …'."""
    kp = " ".join(f"{gain:.4g}" for gain in member.kp)
    kd = " ".join(f"{gain:.4g}" for gain in member.kd)
    return f"kp {kp} / kd {kd}"


def front_table_row(rank: int, member: FrontMember) -> str:
    """One line of the report's front table (public so a test or a caller can find it)."""
    return f"| {rank} | {member.f_acc * 1000:.3f} | {member.f_t:.4g} | {gains_text(member)} |"


def report_markdown(
    *,
    title: str,
    config_lines: Sequence[str],
    history: Sequence[HistoryRow],
    front: Sequence[FrontMember],
    converged: str,
) -> str:
    """The text of report.md (see `write_report`)."""
    lines = [f"# {title}", "", "## Configuration", ""]
    lines += [f"- {line}" for line in config_lines] or ["- (none given)"]
    lines += ["", "## Summary", ""]
    if history:
        last = history[-1]
        lines += [
            f"- generations: {len(history)}",
            f"- evaluations: {last.evaluations}",
            f"- final hypervolume: {last.hypervolume:.6g}",
            f"- best f_acc: {last.best_f_acc * 1000:.3f} mm; best f_t: {last.best_f_t:.4g} (N·m)²",
            f"- wall time: {_duration(last.wall_seconds)}",
        ]
    else:
        lines.append("- no generation finished yet")
    if converged:
        lines.append(f"- {converged}")

    members = sorted_front(front)
    lines += ["", f"## Pareto front ({len(members)} members, most accurate first)", ""]
    if members:
        lines += [
            "| # | f_acc (mm) | f_t ((N·m)²) | gains |",
            "|---:|---:|---:|---|",
            *(front_table_row(rank, member) for rank, member in enumerate(members, start=1)),
        ]
    else:
        lines.append("No members yet.")

    lines += [
        "",
        "## Figures",
        "",
        f"![Pareto front]({PARETO_PNG})",
        "",
        f"![Hypervolume against evaluations]({HYPERVOLUME_PNG})",
        "",
        f"The numbers at full precision: [{FRONT_CSV}]({FRONT_CSV}) (the front, gains and scores) "
        f"and [{HISTORY_CSV}]({HISTORY_CSV}) (one row per generation).",
        "",
    ]
    return "\n".join(lines)


def write_report(
    path: Path,
    *,
    title: str,
    config_lines: Sequence[str],
    history: Sequence[HistoryRow],
    front: Sequence[FrontMember],
    converged: str,
) -> None:
    """A short report.md at `path`: configuration, summary, the front as a table, the figures.

    `converged` is the caller's one-line verdict on why the run stopped (or that it has not),
    e.g. "converged after 240 evaluations (hypervolume gain < 0.1% over 3 generations)". The
    figures and CSVs are linked by their standard names relative to the report, so write them
    into the same directory. The table is rounded for reading; front.csv holds the exact values.
    """
    text = report_markdown(
        title=title, config_lines=config_lines, history=history, front=front, converged=converged
    )
    write_atomically(Path(path), text.encode("utf-8"))
