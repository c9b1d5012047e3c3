"""What a long command says while it works, on stderr, wherever stderr goes.

On a terminal: one live line (rich: a spinner and the text, rewritten in place), cut to fit the
terminal. Anywhere else (a pipe, a file, CI): plain lines, each worth a line in a log, printed
with click.echo and not logged: they are the command's own report, like its last lines, and
the analytic command leaves logging as Python has it (warnings only), so that the in-process
broker of a local farm does not fill the log with its own events.

A tuning run's line (`RunDisplay`) says the generation, the evaluations and their rate, the
hypervolume, the best error and how many workers the farm has now (asked of the broker every
second, whether or not results come), or why nothing moves: "waiting for workers" while the
broker has none, "broker lost, waiting" while the farm's client is waiting for the broker.
"""

import math
import threading
import time
from collections.abc import Callable

import click
from rich.console import Console
from rich.progress import Progress, SpinnerColumn, TaskID, TextColumn

from gainfarm.analytic.tuning.run import RunProgress
from gainfarm.cli.words import counted

NONE_YET = "—"  # a figure no generation has given yet
LOOK_SECONDS = 1.0  # how often the run's line asks the broker how many workers it has
SPINNER_COLUMNS = 2  # the spinner and the space after it


class Display:
    """A live line on a terminal, plain lines elsewhere; a context manager."""

    def __init__(
        self,
        console: Console | None = None,
        enabled: bool = True,
        hushed: Callable[[], bool] = lambda: False,
    ):
        """`enabled` False: say nothing (stderr is someone else's, or the output is JSON).
        `hushed`: whether to say nothing more (a Ctrl-C came: the command's last line is its
        own, however long the main thread takes to stop)."""
        self.console = console or Console(stderr=True)
        self.enabled = enabled
        self.hushed = hushed
        self.live = enabled and self.console.is_terminal
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self._lock = threading.Lock()
        self._logged = -math.inf  # when `every` last printed a line

    @property
    def width(self) -> int:
        """Columns the live line's text may take."""
        return max(20, self.console.width - SPINNER_COLUMNS)

    def __enter__(self) -> "Display":
        if self.live:
            self._progress = Progress(
                SpinnerColumn(),
                TextColumn("{task.description}"),
                console=self.console,
                transient=True,
            )
            self._progress.start()
            self._task = self._progress.add_task("starting")
        return self

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()

    def show(self, text: str) -> None:
        """The live line's text (a terminal only)."""
        if self._progress is not None and self._task is not None:
            self._progress.update(self._task, description=text)

    def log(self, text: str) -> None:
        """A plain line (not on a terminal, where the live line says it)."""
        if self.enabled and not self.live and not self.hushed():
            click.echo(text, err=True)

    def every(self, text: str, seconds: float) -> None:
        """A plain line, unless another was printed less than `seconds` ago (any thread)."""
        with self._lock:
            now = time.monotonic()
            if now - self._logged < seconds:
                return
            self._logged = now
        self.log(text)


def fit(parts: list[tuple[int, str]], width: int) -> str:
    """`parts` (priority, text) joined by " · ", the lowest priorities dropped until the line
    fits in `width` columns; the last one left is cut if it must be."""
    kept = list(parts)
    while len(kept) > 1 and len(" · ".join(text for _, text in kept)) > width:
        kept.remove(min(kept, key=lambda part: part[0]))
    line = " · ".join(text for _, text in kept)
    return line if len(line) <= width else line[: width - 1] + "…"


def _figure(value: float, fmt: str) -> str:
    """`value` formatted, or NONE_YET for the NaN of a figure no generation has given yet."""
    return NONE_YET if math.isnan(value) else fmt.format(value)


def time_left(step: RunProgress) -> float | None:
    """Seconds left until the run's budget is spent, or else until it is expected to converge
    (RunProgress.expected: a fit of its hypervolume's course), at its pace so far (its
    evaluations over its wall time); None with neither, or before any pace."""
    end = step.budget or step.expected
    if end is None or step.elapsed <= 0 or step.evaluations <= 0:
        return None
    return max(end - step.evaluations, 0) / (step.evaluations / step.elapsed)


def left_text(step: RunProgress) -> str:
    """ "; about 3 min left ..." and how that is known, or "" if it is not."""
    left = time_left(step)
    if left is None or left <= 0:  # nothing left to guess: the budget is spent
        return ""
    if step.budget:
        return f"; about {duration_text(left)} left of its {step.budget:,} evaluations at this pace"
    return (
        f"; about {duration_text(left)} left if it converges at about {step.expected:,} "
        "evaluations, as a fit of its hypervolume's course says (a rough guess)"
    )


def duration_text(seconds: float) -> str:
    """A span as a person reads it: '40 s', '3 min', '1 h 20 min'."""
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60} min"


def workers_text(workers: int | None) -> str:
    if workers is None:
        return "workers: ?"
    return counted(workers, "worker")


def live_line(
    step: RunProgress | None, workers: int | None, waiting: str | None, width: int
) -> str:
    """The live line of a tuning run: where it stands, and what holds it up if anything does.
    The generation is the one under way, numbered as history.csv numbers them (from 1)."""
    if waiting is not None:
        state = [(9, "broker lost, waiting")]
    elif workers == 0:
        state = [(9, "waiting for workers")]
    else:
        state = []
    if step is None:
        return fit(state or [(8, "starting"), (7, workers_text(workers))], width)
    rate = step.evaluations / step.elapsed if step.elapsed > 0 else 0.0
    parts = [
        *state,
        (8, f"gen {step.generation + (0 if step.ended else 1)}"),
        (7, f"{step.evaluations:,} evals"),
        (3, f"{rate:.1f}/s"),
        (5, f"HV {_figure(step.hypervolume, '{:.4f}')}"),
        (6, f"best {_figure(step.best_f_acc * 1000, '{:.2f} mm')}"),
    ]
    left = time_left(step)
    # A budget's time left is known, a convergence's guessed (left_text says how); none once spent.
    if left:
        parts.append((7, f"~{duration_text(left)} left{'' if step.budget else '?'}"))
    if not state:
        parts.append((4, workers_text(workers)))
    return fit(parts, width)


def generation_line(step: RunProgress, workers: int | None) -> str:
    """The plain line of a generation that has ended."""
    rate = step.evaluations / step.elapsed if step.elapsed > 0 else 0.0
    return (
        f"generation {step.generation}: {step.evaluations:,} evaluations in "
        f"{step.elapsed:.1f} s ({rate:.1f}/s), hypervolume "
        f"{_figure(step.hypervolume, '{:.4f}')}, best error "
        f"{_figure(step.best_f_acc * 1000, '{:.2f} mm')}, {workers_text(workers)}{left_text(step)}"
    )


class RunDisplay:
    """A tuning run's progress: `step` after each evaluation (the run's on_progress), and a
    look at the farm every LOOK_SECONDS from a thread of its own, so that the line is right even
    while no result comes. `workers()` is how many workers the farm has now (None if the broker
    did not answer), `waiting()` why the farm's client is waiting for the broker (None if it is
    not); both are called from that thread."""

    def __init__(
        self,
        display: Display,
        workers: Callable[[], int | None],
        waiting: Callable[[], str | None],
    ):
        self.display = display
        self._workers = workers
        self._waiting = waiting
        self._step: RunProgress | None = None
        self._count: int | None = None
        self._why: str | None = None
        self._said = ""  # the wait last said in a plain line ("" while none)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()  # look now: the count is stale
        self._thread = threading.Thread(target=self._look, name="progress", daemon=True)

    def __enter__(self) -> "RunDisplay":
        self._refresh()  # the worker count before the first line, not after it
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._wake.set()
        self._thread.join()

    def step(self, step: RunProgress) -> None:
        if step.ended:  # the generation's line says how many workers there are now
            self._refresh()
        with self._lock:
            self._step = step
            if step.ended:
                self.display.log(generation_line(step, self._count))
            if self._count == 0:  # a result came, so some worker has joined since
                self._wake.set()
            self._redraw()

    def _look(self) -> None:
        while True:
            self._wake.wait(LOOK_SECONDS)
            self._wake.clear()
            if self._stop.is_set():
                return
            self._refresh()

    def _refresh(self) -> None:
        count = self._workers()
        why = self._waiting()
        if why is None and count is None:
            why = "the broker does not answer"
        with self._lock:
            self._count, self._why = count, why
            self._redraw()

    def _redraw(self) -> None:
        """The live line; and in plain lines, a wait as it begins and as it ends (held by
        _lock)."""
        self.display.show(live_line(self._step, self._count, self._why, self.display.width))
        if self._why is not None:
            state, text = "lost", f"broker lost, waiting: {self._why}"
        elif self._count == 0:
            state, text = "idle", "waiting for workers: the broker has none"
        else:
            state, text = "", f"going on: {workers_text(self._count)}"
        if state != self._said:
            self.display.log(text)
            self._said = state
