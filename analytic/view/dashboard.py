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

Here: what the page shows, read from the runs' files and the broker (plain data, no Bokeh). The
page itself, built of panels at module level (analytic.view.dashboard_panels: a run's, the runs
compared, one run inspected) and served by analytic.view.dashboard_page, imports Bokeh at its
top; `serve` imports it, the one place the dashboard loads the extra.

Every model a test or a script may want to read is named (`Bokeh.documents[0]
.get_model_by_name(NAME)` in the page): "farm" (the farm's line), "farm-series" (its sources'
columns t, jobs_per_s, queued, busy); "chosen-runs" (the runs compared), "overlay" and "fronts"
(the comparison's sources); "inspect" (the run inspected), "recommendation", "members" (the table's
source, columns members.columns(its arm's joints); its selection is the member chosen), "table",
"export" (the
chosen member's files), "episode-choice", "episode" (which episode, from where) and
"episode-joints", "episode-error", "episode-torques" (its series); and for each run, by its path
as given: "run:PATH" (its line), "history:PATH", "front:PATH", "evaluated:PATH",
"baseline:PATH" and "recommended:PATH" (its sources).
"""

import contextlib
import dataclasses
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
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
from gainfarm.analytic.tuning.evolution import REFERENCE_POINT, normalise
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
from gainfarm.analytic.tuning.run import RunProgress
from gainfarm.analytic.tuning.termination import expected_generations
from gainfarm.analytic.view.figures import log_view, x_view
from gainfarm.analytic.view.members import columns, joints_of, robustness_text, table
from gainfarm.analytic.view.progress import duration_text, left_text
from gainfarm.analytic.view.reports import recommendation_text, run_title
from gainfarm.analytic.view.run_report import advice_text
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.cli.words import counted
from gainfarm.edges.files import lock_held
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR
from gainfarm.schemas.wire import BadMessage, BrokerStatus

if TYPE_CHECKING:
    from bokeh.server.server import Server

REFRESH_SECONDS = 1.0  # how often a page and the farm's status are brought up to date
FARM_HISTORY_SECONDS = 600.0  # the throughput and queue the page plots
DASHBOARD_PORT = 5006  # Bokeh's own default
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
    table: dict[str, list] = field(default_factory=lambda: {name: [] for name in columns(())})
    recommendation: str = ""
    normalised: dict[str, list[float]] = field(default_factory=lambda: {"x": [], "y": []})
    # The front's axes: the run's first two objectives, named with their units.
    axes: tuple[str, str] = PAPER_AXES
    titles: tuple[str, str] = ("f_acc (mm)", "f_t ((N·m)²)")  # the table's objective columns
    joints: tuple[str, ...] = ()  # its arm's joint names: the table's gains, the episode's lines


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
        joints_of(record.config.plant, len(record.front[0].kp) if record.front else None),
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
    """What every page shows, shared: the runs under `roots` (those of the arm `robot`, if
    named), re-read when their files change, and the farm the `session` reaches (None: not
    watched), asked by a thread of its own."""

    def __init__(
        self,
        roots: Sequence[Path],
        session: zenoh.Session | None,
        where: str = "",
        clock: Callable[[], float] = time.monotonic,
        robot: str | None = None,
    ):
        self.roots = list(roots)
        self.robot = robot
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
            if self.robot is None or (
                cached[1].config is not None and cached[1].config.plant.robot == self.robot
            ):
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


class NoBokeh(RuntimeError):
    """The `dashboard` extra is not installed."""


def _page() -> ModuleType:
    """The page's module, which imports Bokeh (the `dashboard` extra); NoBokeh without it."""
    try:
        # optional extra: bokeh (the page and its server); the one place the dashboard loads it
        from gainfarm.analytic.view import dashboard_page
    except ImportError as error:
        if (error.name or "").split(".")[0] not in ("bokeh", "tornado"):
            raise
        raise NoBokeh("the dashboard needs Bokeh: pip install 'gainfarm[dashboard]'") from None
    return dashboard_page


def serve(watch: Watch, port: int, address: str = "127.0.0.1") -> "Server":
    """Bokeh's server for the page on `address`:`port`, started in this thread's event loop (run
    it with `run_forever`, stop it with its `stop`). OSError if the port cannot be had, NoBokeh
    without Bokeh."""
    return _page().serve(watch, port, address)


def run_forever() -> None:
    """Serve until Ctrl-C (the server `serve` started)."""
    _page().run_forever()
