"""`analytic dashboard`: a local web page that shows tuning runs and their farm as they go.

Bokeh's server (the `dashboard` extra) draws the page: it is a well-kept plotting library whose
server pushes new data to the open page over a websocket, and serves its own JavaScript, so the
page works on a machine with no internet access. Each open page gets its own document; all of
them share one `Watch`, which reads the runs' plain files (analytic.records) when they change
and asks the broker for its status (BrokerStatus) once a second, in a thread of its own.

The page, top to bottom: the farm (workers, busy, queued, jobs per second, and the last ten
minutes of throughput and queue); the chosen runs compared (their hypervolume against
evaluations, and their fronts in the space the hypervolume is measured in, one normalisation for
all); one run inspected: its recommendation, its members in a sortable table, a chosen member's
controller files (`analytic export`'s) and one of its episodes plotted from its log
(analytic.view.members); then a panel per run: what it tunes and where it stands, its front over
every evaluated point (as pareto.png draws them: f_acc in mm, f_t on a log axis) with the
recommended member and the default gains, and its hypervolume against evaluations. Runs that
appear under a watched directory while the page is open are added to it.

Every model a test or a script may want to read is named (`Bokeh.documents[0]
.get_model_by_name(NAME)` in the page): "farm" (the farm's line), "farm-series" (its sources'
columns t, jobs_per_s, queued, busy); "chosen-runs" (the runs compared), "overlay" and "fronts"
(the comparison's sources); "inspect" (the run inspected), "recommendation", "members" (the table's
source, columns members.COLUMNS; its selection is the member chosen), "table", "export" (the
chosen member's files), "episode-choice", "episode" (which episode, from where) and
"episode-joints", "episode-error", "episode-torques" (its series); and for each run, by its path
as given: "run:PATH" (its line), "history:PATH", "front:PATH", "evaluated:PATH",
"baseline:PATH" and "recommended:PATH" (its sources).
"""

import contextlib
import dataclasses
import html
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zenoh

from gainfarm.analytic.tuning.check import CHECK_JSON, advice_of, read_check
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import (
    axis_label,
    column_title,
    declarations,
    value_text,
)
from gainfarm.analytic.tuning.evolution import F_T_FLOOR, REFERENCE_POINT, normalise
from gainfarm.analytic.tuning.picks import Pick, picks
from gainfarm.analytic.tuning.records import (
    BASELINE_JSON,
    CONFIG_JSON,
    EPISODES,
    FRONT_JSON,
    HISTORY_CSV,
    LOCK,
    REPORT_MD,
    Baseline,
    FrontMember,
    HistoryRow,
    read_baseline,
    read_run,
    sorted_front,
)
from gainfarm.analytic.tuning.run import RECORD_SECONDS, RunProgress
from gainfarm.analytic.tuning.termination import expected_generations
from gainfarm.analytic.view.figures import log_view, x_view
from gainfarm.analytic.view.members import (
    COLUMNS,
    EMPTY_SERIES,
    GAINS,
    SCORES,
    episode,
    export_links,
    robustness_text,
    series,
    slots,
    table,
)
from gainfarm.analytic.view.progress import duration_text, left_text
from gainfarm.analytic.view.reports import recommendation_text, run_title
from gainfarm.analytic.view.run_report import advice_text
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.cli.words import counted
from gainfarm.edges.files import lock_held
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES
from gainfarm.schemas.limits import MEASURED
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR
from gainfarm.schemas.robot import JOINT_NAMES
from gainfarm.schemas.wire import BadMessage, BrokerStatus

if TYPE_CHECKING:
    from bokeh.server.server import Server

REFRESH_SECONDS = 1.0  # how often a page and the farm's status are brought up to date
FARM_HISTORY_SECONDS = 600.0  # the throughput and queue the page plots
DASHBOARD_PORT = 5006  # Bokeh's own default
TABLE_ROWS_SHOWN = 12  # the member table's rows in view; more scroll
TABLE_ROW_PX = 25  # a row's height in the table (Bokeh's)
SEARCH_DEPTH = 3  # a watched directory's runs: itself, its runs, an experiment's, ...


# --- what the page shows, read from files and the broker -----------------------------------


def axes_of(names: Sequence[str]) -> tuple[str, str]:
    """The front's axes' labels: a run's first two objectives, named with their units."""
    first, second = declarations(names[:2])
    return axis_label(first), axis_label(second)


PAPER_AXES = axes_of(DEFAULT_OBJECTIVES)


def best_text(last: HistoryRow) -> str:
    """The best of the run's first objective so far: "error 12.34 mm" for the paper's f_acc."""
    first = declarations(last.names[:1])[0]
    if first.name == "f_acc":
        return f"error {last.best[0] * 1000:.2f} mm"
    return f"{first.name} {value_text(first, last.best[0])}"


@dataclass(frozen=True)
class RunView:
    """A run as the page draws it: its line of text and its points, ready to plot."""

    line: str
    history: dict[str, list[float]]  # evaluations, hypervolume
    front: dict[str, list[float]]  # f_acc_mm, f_t (step order: by f_acc)
    evaluated: dict[str, list[float]]  # f_acc_mm, f_t
    # The default gains' point (baseline.json), the recommended member's, and when none is
    # recommended the closest to dominating the defaults: none, or one each.
    baseline: dict[str, list[float]] = field(default_factory=lambda: _points([]))
    recommended: dict[str, list[float]] = field(default_factory=lambda: _points([]))
    closest: dict[str, list[float]] = field(default_factory=lambda: _points([]))
    # The front's plot's view (f_acc in mm, f_t), as pareto.png's: the front, the picks and the
    # default gains with a margin, so that a far-off candidate does not squash the front; and
    # how many evaluated points lie outside it. None: no point to frame.
    view: tuple[float, float, float, float] | None = None
    outside: int = 0
    # What the inspector shows of it: its config, its front in front.csv's order, the member
    # table's columns, its recommendation (the controller to use, and how it fared on held-out
    # plants), and its front in the hypervolume's space (x: f_acc, y: f_t, normalised; by x)
    # for the comparison.
    config: RunConfig | None = None
    members: tuple[FrontMember, ...] = ()
    table: dict[str, list] = field(default_factory=lambda: {name: [] for name in COLUMNS})
    recommendation: str = ""
    normalised: dict[str, list[float]] = field(default_factory=lambda: {"x": [], "y": []})
    # The front's axes: the run's first two objectives, named with their units.
    axes: tuple[str, str] = PAPER_AXES
    titles: tuple[str, str] = ("f_acc (mm)", "f_t ((N·m)²)")  # the table's objective columns


# A run's lock state not read yet: the functions below read it themselves (Watch.runs reads it
# once per look and passes it on: the kernel's table of locks, not three reads per run).
UNREAD: Any = object()


def run_view(directory: Path, held: "bool | None" = UNREAD) -> RunView:
    """Where the run in `directory` stands, from its plain files; a run whose files cannot be
    read says why in its line (and shows no points) rather than stopping the page."""
    empty = RunView("", {"evaluations": [], "hypervolume": []}, _points([]), _points([]))
    try:
        record = read_run(directory)
    except FileNotFoundError:
        return dataclasses.replace(empty, line="starting: no config.json yet")
    except (OSError, ValueError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        return dataclasses.replace(empty, line=f"cannot read: {reason}")
    title = run_title(record.config).splitlines()[0]
    state = run_state(directory, held)
    if not record.history:
        if state == "running":
            return dataclasses.replace(empty, line=f"{title}: generation 1 under way; running")
        return dataclasses.replace(empty, line=f"{title}: no generation recorded; {state}")
    last = record.history[-1]
    measured = [point for point in record.evaluated if _measured(point)]
    line = (
        f"{title}: generation {last.generation}, {counted(last.evaluations, 'evaluation')}, "
        f"hypervolume {last.hypervolume:.4g}, best {best_text(last)}, "
        f"front {len(record.front)}; {duration_text(record.wall_seconds)} of tuning"
    )
    if state == "running":  # the time left as the terminal says it, budget or convergence
        config = record.config
        expected = expected_generations(config.termination, [r.hypervolume for r in record.history])
        line += left_text(
            RunProgress(
                generation=last.generation,
                evaluations=last.evaluations,
                hypervolume=last.hypervolume,
                best_f_acc=last.best[0],
                elapsed=record.wall_seconds,
                ended=True,
                budget=config.budget,
                expected=None if expected is None else expected * config.pop,
            )
        ).replace(";", ",", 1)
    line += f"; {state}"
    if penalties := len(record.evaluated) - len(measured):
        line += f" ({penalties} diverged or failed, not drawn)"
    baseline = None
    with contextlib.suppress(OSError, ValueError):
        baseline = read_baseline(directory / BASELINE_JSON)
    check = read_check(directory)
    named = picks(record.front, baseline, advice_of(check))
    chosen = {p.name: p.member for p in named}
    finished = [m.objectives for m in record.front if _measured(m.objectives)]
    # One normalisation for every run: the hypervolume's, at the default reference point.
    x, y = normalise(sorted(finished), REFERENCE_POINT).T.tolist() if finished else ([], [])
    framed = finished + [p.member.objectives for p in named if _measured(p.member.objectives)]
    if baseline is not None and _measured(baseline.objectives):
        framed.append(baseline.objectives)
    view = _view(framed)
    return RunView(
        line,
        {
            "evaluations": [float(row.evaluations) for row in record.history],
            "hypervolume": [row.hypervolume for row in record.history],
        },
        _points(sorted(m.objectives for m in record.front if _measured(m.objectives))),
        _points(measured),
        _points([baseline.objectives] if baseline and _measured(baseline.objectives) else []),
        _points([chosen["recommended"].objectives] if "recommended" in chosen else []),
        _points([chosen["closest"].objectives] if "closest" in chosen else []),
        view,
        _outside(measured, view),
        record.config,
        tuple(sorted_front(record.front)),
        table(record.front, named, record.config, check),
        _recommendation(named, baseline, state, record.config, check),
        {"x": x, "y": y},
        axes_of(record.config.objectives),
        tuple(column_title(o) for o in declarations(record.config.objectives[:2])),
    )


def _recommendation(
    named: list[Pick], baseline: Baseline | None, state: str, config: RunConfig, check: dict | None
) -> str:
    """The run's recommendation as report.md's first line says it, or that it has none yet;
    then how that controller fared on the held-out plants, or when it will be known."""
    if not named:
        return "No front yet."
    if baseline is None and state != "report written":
        knee = next(p for p in named if p.name == "knee")
        said = (
            "No recommendation yet: the default gains are scored as the run ends, and the "
            f"recommended member is the knee among those that beat them (the knee so far: row "
            f"{knee.row})."
        )
    else:
        said = (advice_text(check) or recommendation_text(named, baseline)).replace("**", "")
    if check is None and config.check_plants and state.startswith("running"):
        held = (
            f"Held-out check: on {counted(len(config.check_plants), 'plant')}, once the run ends."
        )
    else:
        held = robustness_text(named, check, len(config.check_plants))
    return f"{said} {held}"


def _view(points: Sequence[tuple[float, float]]) -> tuple[float, float, float, float] | None:
    """The frame of `points` (f_acc in m, f_t) as pareto.png frames its view (figures'
    x_view and log_view): f_acc in mm, f_t on a log axis."""
    if not points:
        return None
    x = x_view([f_acc * 1000.0 for f_acc, _ in points])
    y = log_view([max(f_t, 1e-12) for _, f_t in points])
    return (*x, *y)


def _outside(points: Sequence[tuple[float, float]], view: "tuple | None") -> int:
    if view is None:
        return 0
    x_low, x_high, y_low, y_high = view
    return sum(
        1
        for f_acc, f_t in points
        if not (x_low <= f_acc * 1000.0 <= x_high and y_low <= f_t <= y_high)
    )


def run_state(directory: Path, held: "bool | None" = UNREAD) -> str:
    """Running while a process holds the run's lock (`held`, lock_held's answer); else
    finished (its report written) or stopped before it ended (`analytic resume` continues it)."""
    if held is UNREAD:
        held = lock_held(directory / LOCK)
    if held:
        return "running"
    if (directory / REPORT_MD).exists():
        return "report written"
    if held is None:  # the kernel's table of locks could not be read: no telling
        return "running, or stopped"
    return "stopped: `analytic resume` continues it"


def live_first(
    directories: Sequence[Path], held: "Mapping[Path, bool | None] | None" = None
) -> list[Path]:
    """The runs in the order the page shows them: running ones first (`held`: each one's lock
    state, read here if not given), then the newest (by when their config.json was written), so
    that the run one is watching is at the top."""

    def key(directory: Path) -> tuple[bool, int]:
        try:
            made = (directory / CONFIG_JSON).stat().st_mtime_ns
        except OSError:
            made = 0
        running = held[directory] if held is not None else lock_held(directory / LOCK)
        return (not running, -made)

    return sorted(directories, key=key)


def _measured(point: tuple[float, float]) -> bool:
    """A point the page can draw: finite, and not a divergence's penalty."""
    f_acc, f_t = point
    return math.isfinite(f_acc) and math.isfinite(f_t) and f_acc < DIVERGED_TICK_ERROR


def _points(points: Sequence[tuple[float, float]]) -> dict[str, list[float]]:
    # A log axis cannot show f_t <= 0: such points sit at a floor far below any real value.
    return {
        "f_acc_mm": [f_acc * 1000.0 for f_acc, _ in points],
        "f_t": [max(f_t, 1e-12) for _, f_t in points],
    }


def find_runs(roots: Sequence[Path]) -> list[Path]:
    """The run directories (those holding a config.json) at or under `roots`, a few levels
    down, in a stable order; an episodes/ directory is never searched (it holds only logs)."""
    found: list[Path] = []

    def search(directory: Path, depth: int) -> None:
        if (directory / CONFIG_JSON).is_file():
            found.append(directory)
            return
        if depth == 0:
            return
        with contextlib.suppress(OSError):
            for child in sorted(directory.iterdir()):
                if child.is_dir() and child.name != EPISODES and not child.name.startswith("."):
                    search(child, depth - 1)

    for root in roots:
        search(root, SEARCH_DEPTH)
    return list(dict.fromkeys(found))


@dataclass
class FarmSeries:
    """The farm's last ten minutes, a point per look: seconds since the dashboard started, its
    throughput, its queue and its busy workers."""

    t: deque[float] = field(default_factory=deque)
    jobs_per_s: deque[float] = field(default_factory=deque)
    queued: deque[float] = field(default_factory=deque)
    busy: deque[float] = field(default_factory=deque)

    def add(self, t: float, farm: BrokerStatus) -> None:
        for column, value in (
            (self.t, t),
            (self.jobs_per_s, farm.jobs_per_s),
            (self.queued, farm.queued),
            (self.busy, farm.busy),
        ):
            column.append(float(value))
        while self.t and self.t[0] < t - FARM_HISTORY_SECONDS:
            for column in (self.t, self.jobs_per_s, self.queued, self.busy):
                column.popleft()

    def columns(self) -> dict[str, list[float]]:
        return {
            "t": list(self.t),
            "jobs_per_s": list(self.jobs_per_s),
            "queued": list(self.queued),
            "busy": list(self.busy),
        }


def farm_line(farm: BrokerStatus) -> str:
    return (
        f"{counted(farm.worker_count, 'worker')} ({farm.busy} busy), {farm.queued} queued, "
        f"{farm.jobs_per_s:.1f} jobs/s over the last minute, "
        f"{counted(farm.jobs_done, 'job')} done, {counted(farm.study_count, 'study')}"
    )


class Watch:
    """What every page shows, shared: the runs under `roots`, re-read when their files change,
    and the farm the `session` reaches (None: not watched), asked by a thread of its own."""

    def __init__(
        self,
        roots: Sequence[Path],
        session: zenoh.Session | None,
        where: str = "",
        clock: Callable[[], float] = time.monotonic,
    ):
        self.roots = list(roots)
        self.session = session
        self.where = where
        self.clock = clock
        self.started = clock()
        self.farm = FarmSeries()
        self.farm_text = "farm: not watched (--connect ENDPOINT shows it)"
        self.farm_version = 0
        self._views: dict[Path, tuple[object, RunView]] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> "Watch":
        if self.session is not None:
            self.farm_text = f"farm at {self.where}: asking the broker"
            self._thread = threading.Thread(target=self._ask, name="farm", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def _ask(self) -> None:
        assert self.session is not None
        while not self._stop.is_set():
            try:
                farm = query_status(self.session, timeout=2 * REFRESH_SECONDS)
                text = f"farm at {self.where}: {farm_line(farm)}"
            except (BrokerUnavailable, BadMessage) as error:
                farm, text = None, f"farm at {self.where}: {error}"
            except Exception as error:  # a closed session, a library's error: said, not fatal
                farm, text = None, f"farm at {self.where}: cannot ask: {error}"
            with self._lock:
                if farm is not None:
                    self.farm.add(self.clock() - self.started, farm)
                self.farm_text = text
                self.farm_version += 1
            self._stop.wait(REFRESH_SECONDS)

    def farm_now(self) -> tuple[int, str, dict[str, list[float]]]:
        """The farm's line and series, and a version that changes when they do."""
        with self._lock:
            return self.farm_version, self.farm_text, self.farm.columns()

    def runs(self) -> list[tuple[Path, object, RunView]]:
        """Every run found now: its path, a version that changes when its files do, its view."""
        views = []
        found = find_runs(self.roots)
        held = {directory: lock_held(directory / LOCK) for directory in found}
        for directory in live_first(found, held):
            version = (_version(directory), held[directory])  # its process starting or ending
            with self._lock:
                cached = self._views.get(directory)
            if cached is None or cached[0] != version:
                cached = (version, run_view(directory, held[directory]))
                with self._lock:
                    self._views[directory] = cached
            views.append((directory, *cached))
        return views


def _version(directory: Path) -> object:
    """What changes when a run writes its records (history.csv is written last, front.json
    before it) or its report."""
    stamps = []
    for name in (CONFIG_JSON, FRONT_JSON, HISTORY_CSV, REPORT_MD, CHECK_JSON):
        try:
            stamps.append((directory / name).stat().st_mtime_ns)
        except OSError:
            stamps.append(None)
    return tuple(stamps)


# --- the page -------------------------------------------------------------------------------


# The lines' colours: a joint's, and a compared run's in the page's order (matplotlib's tab10,
# as the figures, then tab20's lighter ten: twenty runs before a colour comes again).
COLOURS = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
)  # fmt: skip
RUN_COLOURS = (
    *COLOURS,
    "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5",
    "#c49c94", "#f7b6d2", "#c7c7c7", "#dbdb8d", "#9edae5",
)  # fmt: skip


def _colour(k: int) -> str:
    """The colour of the k-th run compared."""
    return RUN_COLOURS[k % len(RUN_COLOURS)]


def _legend_beside(plot: Any) -> None:
    """The plot's legend to the right of its axes, where it covers no point; a click on an
    entry hides what it names."""
    legend = plot.legend[0]
    legend.click_policy = "hide"
    legend.label_text_font_size = "9pt"
    plot.add_layout(legend, "right")


def page(watch: Watch) -> Callable:
    """The function Bokeh calls to build each new page's document."""
    from bokeh.layouts import column, row
    from bokeh.models import (
        ColumnDataSource,
        DataTable,
        Div,
        MultiChoice,
        NumberFormatter,
        Range1d,
        Select,
        TableColumn,
    )
    from bokeh.plotting import figure

    wide = {"sizing_mode": "stretch_width"}  # the window's width, shared by a row's plots

    class RunPanel:
        """A run's part of the page: its heading, its line, its front and its curve."""

        def __init__(self, directory: Path):
            key = str(directory)
            self.shown: object = None  # the run's version on the page
            self.line = Div(name=f"run:{key}", text="")
            self.recommendation = Div(name=f"recommendation:{key}", text="", **wide)
            self.history = ColumnDataSource(
                {"evaluations": [], "hypervolume": []}, name=f"history:{key}"
            )
            self.front = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"front:{key}")
            self.evaluated = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"evaluated:{key}")
            self.baseline = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"baseline:{key}")
            self.recommended = ColumnDataSource(
                {"f_acc_mm": [], "f_t": []}, name=f"recommended:{key}"
            )
            self.closest = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"closest:{key}")
            self.pareto = pareto = figure(
                title="front over every evaluated point",
                x_axis_label=PAPER_AXES[0],
                y_axis_label=PAPER_AXES[1],
                y_axis_type="log",
                x_range=Range1d(0, 1),
                y_range=Range1d(1e-2, 1e4),
                height=360,
                **wide,
            )
            pareto.scatter("f_acc_mm", "f_t", source=self.evaluated, size=4, color="lightgrey")
            pareto.step("f_acc_mm", "f_t", source=self.front, mode="after", color="crimson")
            pareto.scatter("f_acc_mm", "f_t", source=self.front, size=6, color="crimson")
            pareto.scatter(
                "f_acc_mm", "f_t", source=self.recommended, size=18, marker="star",
                color="gold", line_color="black", legend_label="recommended (use this)",
            )  # fmt: skip
            pareto.scatter(
                "f_acc_mm", "f_t", source=self.closest, size=14, marker="plus",
                color="darkorange", line_color="black",
                legend_label="none recommended: closest to the defaults",
            )  # fmt: skip
            pareto.scatter(
                "f_acc_mm", "f_t", source=self.baseline, size=12, marker="x", color="black",
                line_width=2, legend_label="default gains",
            )  # fmt: skip
            # Below the axes, across: beside them, the long names would squeeze the front.
            self.marks = pareto.legend[0].items  # recommended, closest, default gains
            pareto.legend[0].orientation = "horizontal"
            pareto.add_layout(pareto.legend[0], "below")
            curve = figure(
                title="hypervolume (normalised: 0 to 1)",
                x_axis_label="evaluations",
                y_axis_label="hypervolume",
                height=360,
                **wide,
            )
            curve.line("evaluations", "hypervolume", source=self.history, line_width=2)
            curve.scatter("evaluations", "hypervolume", source=self.history, size=5)
            heading = Div(text=f"<h3>{html.escape(key)}</h3>")
            self.layout = column(
                heading, self.line, self.recommendation, row(pareto, curve, **wide), **wide
            )

        def show(self, version: object, view: RunView) -> None:
            if version != self.shown:
                self.line.text = html.escape(view.line)
                self.recommendation.text = html.escape(view.recommendation)
                if view.view is not None:  # framed as pareto.png is: the front, not the cloud
                    x_low, x_high, y_low, y_high = view.view
                    self.pareto.x_range.update(start=x_low, end=x_high)
                    self.pareto.y_range.update(start=y_low, end=y_high)
                outside = f" ({view.outside} outside the view)" if view.outside else ""
                self.pareto.title.text = f"front over every evaluated point{outside}"
                self.pareto.xaxis.axis_label, self.pareto.yaxis.axis_label = view.axes
                self.closest.data = view.closest
                for item, points in zip(
                    self.marks, (view.recommended, view.closest, view.baseline), strict=True
                ):
                    item.visible = bool(points["f_acc_mm"])  # no entry for what is not drawn
                self.history.data = view.history
                self.front.data = view.front
                self.evaluated.data = view.evaluated
                self.baseline.data = view.baseline
                self.recommended.data = view.recommended
                self.shown = version

    class Compare:
        """The chosen runs side by side: their hypervolume curves and their fronts, each in the
        hypervolume's normalised space, so that runs of other populations and budgets compare.
        Every run is chosen as it appears; one taken out of the choice stays out."""

        def __init__(self) -> None:
            self.choice = MultiChoice(name="chosen-runs", title="runs compared", **wide)
            self.overlay = ColumnDataSource(
                {"xs": [], "ys": [], "run": [], "colour": []}, name="overlay"
            )
            self.fronts = ColumnDataSource(
                {"xs": [], "ys": [], "run": [], "colour": []}, name="fronts"
            )
            self.points = ColumnDataSource({"x": [], "y": [], "colour": []}, name="front-points")
            curves = figure(
                title="hypervolume (normalised: 0 to 1) against evaluations",
                x_axis_label="evaluations",
                y_axis_label="hypervolume",
                height=320,
                **wide,
            )
            curves.multi_line(
                "xs", "ys", source=self.overlay, line_color="colour", line_width=2,
                legend_field="run",
            )  # fmt: skip
            _legend_beside(curves)
            fronts = figure(
                title=(
                    f"fronts in the hypervolume's space: f_acc / {REFERENCE_POINT[0] * 1000:g} "
                    f"mm, log f_t ({F_T_FLOOR:g} → 0, {REFERENCE_POINT[1]:g} → 1)"
                ),
                x_axis_label=f"f_acc / {REFERENCE_POINT[0] * 1000:g} mm",
                y_axis_label="log f_t (normalised)",
                height=320,
                **wide,
            )
            fronts.multi_line(
                "xs", "ys", source=self.fronts, line_color="colour", line_width=2,
                legend_field="run",
            )  # fmt: skip
            fronts.scatter("x", "y", source=self.points, color="colour", size=5)
            _legend_beside(fronts)
            self.layout = column(self.choice, row(curves, fronts, **wide), **wide)
            self.known: list[str] = []
            self.shown: object = None
            self.found: list[tuple[Path, object, RunView]] = []
            self.choice.on_change("value", lambda _attr, _old, _new: self.draw())

        def show(self, found: list[tuple[Path, object, RunView]]) -> None:
            self.found = found
            names = [str(directory) for directory, _, _ in found]
            new = [name for name in names if name not in self.known]
            self.known += new
            if self.choice.options != names:
                self.choice.options = names
            if new:
                self.choice.value = [*self.choice.value, *new]  # draws, through on_change
            self.draw()

        def draw(self) -> None:
            chosen = set(self.choice.value)
            shown = [
                (k, directory, view)
                for k, (directory, _, view) in enumerate(self.found)
                if str(directory) in chosen
            ]
            version = [(directory, v) for directory, v, _ in self.found if str(directory) in chosen]
            if version == self.shown:
                return
            self.shown = version
            curves = [(k, d, v) for k, d, v in shown if v.history["evaluations"]]
            self.overlay.data = {
                "xs": [view.history["evaluations"] for _, _, view in curves],
                "ys": [view.history["hypervolume"] for _, _, view in curves],
                "run": [str(directory) for _, directory, _ in curves],
                "colour": [_colour(k) for k, _, _ in curves],
            }
            fronts = [(k, d, v) for k, d, v in shown if v.normalised["x"]]
            self.fronts.data = {
                "xs": [view.normalised["x"] for _, _, view in fronts],
                "ys": [view.normalised["y"] for _, _, view in fronts],
                "run": [str(directory) for _, directory, _ in fronts],
                "colour": [_colour(k) for k, _, _ in fronts],
            }
            self.points.data = {
                "x": [x for _, _, view in fronts for x in view.normalised["x"]],
                "y": [y for _, _, view in fronts for y in view.normalised["y"]],
                "colour": [_colour(k) for k, _, view in fronts for _ in view.normalised["x"]],
            }

    class Inspector:
        """One run looked into: its recommendation, its members in a sortable table, and the member
        chosen there: its controller files and one of its episodes, plotted."""

        def __init__(self) -> None:
            self.run: Path | None = None
            self.view: RunView | None = None
            self.shown: object = None
            self.chosen: FrontMember | None = None
            self.drawn: tuple[Path, FrontMember, int] | None = None  # run, member, row shown
            self.found: dict[str, tuple[object, RunView]] = {}  # every run: version, view
            self.choice = Select(name="inspect", title="run inspected", options=[], value="")
            self.recommendation = Div(name="recommendation", text="", **wide)
            self.members = ColumnDataSource({name: [] for name in COLUMNS}, name="members")
            self.table = DataTable(
                name="table",
                source=self.members,
                columns=_table_columns(TableColumn, NumberFormatter),
                sortable=True,
                selectable=True,
                index_position=None,
                autosize_mode="none",
                height=TABLE_ROWS_SHOWN * TABLE_ROW_PX + TABLE_ROW_PX,
                **wide,
            )
            self.export = Div(name="export", text=NOTHING_CHOSEN, **wide)
            self.episode_choice = Select(name="episode-choice", title="episode", options=[])
            self.episode = Div(name="episode", text="", **wide)
            self.joints = ColumnDataSource(EMPTY_SERIES["joints"], name="episode-joints")
            self.error = ColumnDataSource(EMPTY_SERIES["error"], name="episode-error")
            self.torques = ColumnDataSource(EMPTY_SERIES["torques"], name="episode-torques")
            angles = figure(
                title="joint angles: measured (solid), reference (dashed)",
                x_axis_label="time (s)",
                y_axis_label="rad",
                height=300,
                **wide,
            )
            error = figure(
                title="tracking error: distance from the desired point",
                x_axis_label="time (s)",
                y_axis_label="mm",
                height=300,
                **wide,
            )
            error.line("t", "error_mm", source=self.error, line_width=2)
            torques = figure(
                title="torques: command (solid), measured (dashed)",
                x_axis_label="time (s)",
                y_axis_label="N·m",
                height=300,
                **wide,
            )
            for j, joint in enumerate(JOINT_NAMES):
                solid = {"color": COLOURS[j], "legend_label": joint}
                dashed = {**solid, "line_dash": "dashed"}  # one legend entry hides both
                angles.line("t", f"q_{joint}", source=self.joints, **solid)
                angles.line("t", f"q_des_{joint}", source=self.joints, **dashed)
                torques.line("t", f"u_{joint}", source=self.torques, **solid)
                torques.line("t", f"tau_{joint}", source=self.torques, **dashed)
            for plot in (angles, torques):
                _legend_beside(plot)
            self.layout = column(
                self.choice, self.recommendation, self.table, self.export, self.episode_choice,
                self.episode, row(angles, error, torques, **wide), **wide,
            )  # fmt: skip
            self.choice.on_change("value", lambda _attr, _old, _new: self.refresh())
            self.members.selected.on_change("indices", lambda _attr, _old, _new: self.pick())
            self.episode_choice.on_change("value", lambda _attr, _old, _new: self.plot())

        def show(self, found: list[tuple[Path, object, RunView]]) -> None:
            names = [str(directory) for directory, _, _ in found]
            if self.choice.options != names:
                self.choice.options = names
            if self.choice.value not in names and names:
                self.choice.value = names[0]  # the run at the top: running, or the newest
            self.found = {str(directory): (version, view) for directory, version, view in found}
            self.refresh()

        def refresh(self) -> None:
            version, view = self.found.get(self.choice.value, (None, None))
            if view is None or (self.choice.value, version) == self.shown:
                return
            if self.run != Path(self.choice.value):
                self.chosen = None
            self.run, self.view = Path(self.choice.value), view
            self.shown = (self.choice.value, version)
            self.recommendation.text = html.escape(view.recommendation)
            self.members.data = view.table
            titles = dict(zip(SCORES, view.titles, strict=True))  # the run's objectives
            for item in self.table.columns:
                item.title = titles.get(item.field, item.title)
            # As tall as its rows, up to TABLE_ROWS_SHOWN (then it scrolls): no blank below.
            shown = min(max(len(view.members), 1), TABLE_ROWS_SHOWN)
            self.table.height = (shown + 1) * TABLE_ROW_PX + TABLE_ROW_PX // 2
            # The member chosen stays chosen while it is on the front (its row may move).
            keep = [i for i, m in enumerate(view.members) if m == self.chosen]
            if self.members.selected.indices != keep:
                self.members.selected.indices = keep  # picks again, through on_change
            else:
                self.pick()

        def pick(self) -> None:
            view, indices = self.view, self.members.selected.indices
            if view is None or self.run is None or not indices or indices[0] >= len(view.members):
                self.chosen = self.drawn = None
                self.export.text = NOTHING_CHOSEN
                self.episode_choice.options, self.episode.text = [], ""
                for source, empty in self._episode_sources():
                    source.data = empty
                return
            member = view.members[indices[0]]
            if (self.run, member, indices[0] + 1) == self.drawn:
                return  # the same member at the same row, drawn already
            self.chosen, self.drawn = member, (self.run, member, indices[0] + 1)
            self.export.text = export_links(self.run, indices[0] + 1)
            assert view.config is not None  # a run with members has its config
            labels = [slot.label() for slot in slots(view.config)]
            if self.episode_choice.options != labels:
                self.episode_choice.options = labels
            if self.episode_choice.value != labels[0]:
                self.episode_choice.value = labels[0]  # plots, through on_change
            else:
                self.plot()

        def plot(self) -> None:
            view, member = self.view, self.chosen
            if view is None or view.config is None or member is None or self.run is None:
                return
            labels = [slot.label() for slot in slots(view.config)]
            if self.episode_choice.value not in labels:
                return
            slot = slots(view.config)[labels.index(self.episode_choice.value)]
            found, where = episode(self.run, view.config, member, slot)
            row_number = view.members.index(member) + 1
            said = f"row {row_number}, {slot.label()}: {where}."
            if view.config.model.interface == "fri":  # what the dashed torques hold
                said += (
                    " Its measured torques hold the gravity torque the robot's own "
                    "compensation adds under the command (FRI torque mode)."
                )
            self.episode.text = html.escape(said)
            drawn = series(found) if found is not None else EMPTY_SERIES
            for (source, _), name in zip(
                self._episode_sources(), ("joints", "error", "torques"), strict=True
            ):
                source.data = drawn[name]

        def _episode_sources(self) -> list[tuple[Any, dict]]:
            return [
                (self.joints, EMPTY_SERIES["joints"]),
                (self.error, EMPTY_SERIES["error"]),
                (self.torques, EMPTY_SERIES["torques"]),
            ]

    def build(document) -> None:  # bokeh.document.Document
        farm_line = Div(name="farm", text="", styles={"font-size": "110%"})
        farm_series = ColumnDataSource(
            {"t": [], "jobs_per_s": [], "queued": [], "busy": []}, name="farm-series"
        )
        since = "seconds since the dashboard started"
        throughput = figure(
            title="throughput (jobs/s over the last minute)",
            x_axis_label=since,
            height=220,
            **wide,
        )
        throughput.line("t", "jobs_per_s", source=farm_series, line_width=2)
        queue = figure(title="queued jobs and busy workers", x_axis_label=since, height=220, **wide)
        queue.line("t", "queued", source=farm_series, line_width=2, legend_label="queued")
        queue.line(
            "t", "busy", source=farm_series, line_width=2, color="orange", legend_label="busy"
        )
        queue.legend.location = "top_left"
        compare, inspector = Compare(), Inspector()
        roots = ", ".join(map(str, watch.roots))
        heading = Div(
            text=f"<h2>runs</h2>under {html.escape(roots)}: running ones first, then the "
            f"newest, each as its records say (a run writes them every {RECORD_SECONDS:g} s "
            "and as it stops, so a running one's may be that far behind its terminal)"
        )
        runs = column(heading, **wide)
        panels: dict[Path, RunPanel] = {}
        farm_shown = [-1]  # the farm's version on the page

        def update() -> None:
            version, text, series = watch.farm_now()
            if version != farm_shown[0]:
                farm_line.text = html.escape(text)
                farm_series.data = series
                farm_shown[0] = version
            found = watch.runs()
            for directory, run_version, view in found:
                if directory not in panels:
                    panels[directory] = RunPanel(directory)
                panels[directory].show(run_version, view)
            order = [heading, *(panels[directory].layout for directory, _, _ in found)]
            if list(runs.children) != order:  # a new run, or one that stopped: reordered
                runs.children = order
            compare.show(found)
            inspector.show(found)

        document.title = "gainfarm dashboard"
        farm = [Div(text="<h2>gainfarm</h2>"), farm_line, row(throughput, queue, **wide)]
        compared = [Div(text="<h2>compare</h2>"), compare.layout]
        inspected = [Div(text="<h2>inspect</h2>"), inspector.layout]
        document.add_root(column(*farm, *compared, *inspected, runs, **wide))
        update()
        document.add_periodic_callback(update, int(REFRESH_SECONDS * 1000))

    return build


NOTHING_CHOSEN = "choose a member in the table: its controller files and an episode show here"


def _table_columns(column: type, number: type) -> list:
    """The member table's columns (bokeh's TableColumn, NumberFormatter), each sortable."""

    def numeric(field: str, title: str, fmt: str, width: int = 70) -> Any:
        return column(field=field, title=title, formatter=number(format=fmt), width=width)

    # Widths that hold their headers and values whole (the table scrolls sideways); a measure's
    # title is its name's first word ("saturated", for saturated_fraction).
    return [
        column(field="row", title="row", width=45),
        column(field="picked", title="picked", width=170),
        numeric("f_acc_mm", "f_acc (mm)", "0.000", 95),
        numeric("f_t", "f_t ((N·m)²)", "0.0000", 105),
        *(numeric(name, name.replace("_", " "), "0", 70) for name in GAINS[: len(JOINT_NAMES)]),
        *(numeric(name, name.replace("_", " "), "0.00", 65) for name in GAINS[len(JOINT_NAMES) :]),
        *(numeric(name, name.split("_")[0], "0.000", 90) for name in MEASURED),
        column(field="limits", title="limits", width=110),
        column(field="validation", title="validation", width=200),
        column(field="held_out", title="held-out plants", width=520),
    ]


class NoBokeh(RuntimeError):
    """The `dashboard` extra is not installed."""


def serve(watch: Watch, port: int, address: str = "127.0.0.1") -> "Server":
    """Bokeh's server for the page on `address`:`port`, started in this thread's event loop (run
    it with `run_forever`, stop it with its `stop`). OSError if the port cannot be had, NoBokeh
    without Bokeh."""
    try:
        from bokeh.application import Application
        from bokeh.application.handlers.function import FunctionHandler
        from bokeh.server.server import Server
    except ImportError:
        raise NoBokeh("the dashboard needs Bokeh: pip install 'gainfarm[dashboard]'") from None

    server = Server(
        {"/": Application(FunctionHandler(page(watch)))},
        port=port,
        address=address,
        allow_websocket_origin=[f"{address}:{port}", f"localhost:{port}"],
        num_procs=1,
    )
    server.start()
    return server


def run_forever() -> None:
    """Serve until Ctrl-C: Tornado's loop, woken every so often so that a Ctrl-C is seen."""
    from tornado.ioloop import IOLoop, PeriodicCallback

    from gainfarm.cli import interrupts

    loop = IOLoop.current()

    def check() -> None:
        if interrupts.INTERRUPTED.is_set():
            loop.stop()

    PeriodicCallback(check, 200).start()
    loop.start()
    interrupts.check()
