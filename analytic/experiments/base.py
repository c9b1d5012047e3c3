"""What every experiment shares: the runner, the normalised space its verdicts are taken in, the
report's frame, and the declaration by which the registry finds an experiment.

An experiment is a set of tuning runs (one directory each under OUT/runs/, resumable: a finished
run is kept, an unfinished one resumed), with cross-evaluations of their fronts where the
experiment needs them, all at once (up to `Experiment.parallel`, each run with its own farm
study, so an experiment is as wide as the farm); then results.csv, stats.csv
(analytic.experiments.statistics: tests, effect sizes and confidence intervals behind every
verdict), normalisation.json, a figure and report.md.

Hypervolumes within an experiment are taken in one normalised space per problem (one trajectory
the fronts are judged on): between the ideal and the nadir point of the pooled non-dominated
front of every front the experiment judged on that problem, f_acc linearly and f_t on a log scale
(as analytic.tuning.evolution.normalise does), against the reference point 1.1 × (nadir − ideal)
beyond the ideal, as a fraction of that box. Penalty points (NO_EPISODE, a diverged episode, any
point with a mean error of DIVERGED_TICK_ERROR or more) never set the ideal or the nadir, so the
values spread over the range where the controllers really differ. normalisation.json records the
ideal and the nadir of each problem.

Each experiment is one module of this package (popsize, generic_vs_specific, speed, algorithms,
dataset_value, feedforward, sensitivity) owning its computation, its table and its figure,
declared by an `ExperimentSpec` named EXPERIMENT and found through the entry-point group
`gainfarm.experiments` (analytic.experiments: the registry). The runs are read back from their
plain files (analytic.tuning.records), never from their checkpoints.
"""

import functools
import itertools
import json
import math
import threading
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pymoo.indicators.hv import HV

from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import F_T_FLOOR, REFERENCE_POINT, non_dominated_indices
from gainfarm.analytic.tuning.records import (
    CONFIG_JSON,
    REPORT_MD,
    FrontMember,
    RunRecord,
    read_run,
    results_csv,
)
from gainfarm.analytic.tuning.run import RunBusy, TuningRun, upgrade
from gainfarm.analytic.view.reports import plant_text
from gainfarm.analytic.view.run_report import write_run_report
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR, NO_EPISODE
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec
from gainfarm.schemas.wire import one_line

K = TypeVar("K", bound=Hashable)
T = TypeVar("T")

ALL_KINDS = (TrajectoryKind.spiral, TrajectoryKind.random, TrajectoryKind.pyramid)
MARGIN = 0.1  # the reference point lies this fraction of (nadir - ideal) beyond the nadir
NORMALISATION_JSON = "normalisation.json"
STATS_CSV = "stats.csv"
BUSY_POLL_SECONDS = 2.0  # how often a run another process is running is looked at again
_BUSY = object()  # what a task whose run another process is running gives first

Point = tuple[float, float]

# An evaluator for one run or cross-evaluation: given the farm study name it may use and the
# directory its logs go to, a context manager (FarmClient, InProcessEvaluator).
EvaluatorFactory = Callable[[str, Path], AbstractContextManager[Evaluator]]


# --- the declaration the registry finds --------------------------------------------------------


@dataclass(frozen=True)
class Option:
    """An option of one experiment's own on the command line (`analytic experiment NAME`).

    `parse` turns the text given (or `default`) into the keyword `parameter` of the
    experiment's run; a ValueError says, in one line, what is wrong with it (the command puts
    the option's name in front)."""

    flag: str  # "--sizes"
    parameter: str  # "sizes"
    help: str
    default: str | None = None  # as typed; None: the run's own default, unless given
    parse: Callable[[str], object] = str
    metavar: str = "TEXT"


def _same(base: RunConfig, _options: Mapping[str, Any]) -> RunConfig:
    return base


def _base_trajectories(base: RunConfig, _options: Mapping[str, Any]) -> Sequence[TrajectorySpec]:
    return base.trajectories


@dataclass(frozen=True)
class ExperimentSpec:
    """One experiment as the registry and the command line know it.

    `run(experiment, base, reps, **options)` does it all: the runs, results.csv, stats.csv,
    normalisation.json, its figure and report.md. Before anything runs, `prepare(base,
    options)` checks the options against the base configuration and returns the one the runs
    start from (ValueError, naming the option, if they do not fit), and `trajectories(base,
    options)` are every trajectory its episodes follow, which the command checks the arm can
    follow (blaming `trajectory_option`)."""

    name: str  # as `analytic experiment NAME` names it
    summary: str  # one line
    run: Callable[..., object]
    help: str = ""  # what `analytic experiment NAME --help` says; the summary if empty
    options: tuple[Option, ...] = ()
    duration: float | None = 5.0  # --duration's default, s; None: it takes no --duration
    prepare: Callable[[RunConfig, Mapping[str, Any]], RunConfig] = _same
    trajectories: Callable[[RunConfig, Mapping[str, Any]], Sequence[TrajectorySpec]] = (
        _base_trajectories
    )
    trajectory_option: str = "--duration"


def numbers(kind: Callable[[float], T]) -> Callable[[str], list[T]]:
    """A parser of comma-separated numbers, each made `kind` (int, float)."""

    def parse(text: str) -> list[T]:
        try:
            values = [float(part) for part in text.split(",")]
        except ValueError:
            raise ValueError(f"expected comma-separated numbers, got {text!r}") from None
        return [kind(value) for value in values]

    return parse


def at_least(minimum: int) -> Callable[[str], int]:
    """A parser of one integer no smaller than `minimum`."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise ValueError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise ValueError(f"{value} is not at least {minimum}")
        return value

    return parse


# --- the runner ----------------------------------------------------------------------------------


def is_penalty(point: Point, penalised: frozenset[Point] | set[Point] = frozenset()) -> bool:
    """A penalty rather than a measured controller: no episode, a diverged one (`penalised`), a
    mean error no finished episode reaches, or a non-finite value."""
    return (
        point == NO_EPISODE
        or point in penalised
        or not (math.isfinite(point[0]) and math.isfinite(point[1]))
        or point[0] >= DIVERGED_TICK_ERROR
    )


def _unless_busy(task: Callable[[], T]) -> T | object:
    """The task's result, or _BUSY if another process is running its run."""
    try:
        return task()
    except RunBusy:
        return _BUSY


@dataclass(frozen=True)
class Normalisation:
    """The normalised objective space of one problem: ideal → 0, nadir → 1 (f_t on a log
    scale, floored at F_T_FLOOR)."""

    ideal: Point
    nadir: Point

    @classmethod
    def of(
        cls,
        point_sets: Sequence[Sequence[Point]],
        penalised: frozenset[Point] | set[Point] = frozenset(),
    ) -> "Normalisation":
        """Between the ideal and the nadir of the pooled non-dominated front of `point_sets`,
        penalty points left out; the fixed REFERENCE_POINT box if no point is left."""
        pooled = [p for points in point_sets for p in points if not is_penalty(p, penalised)]
        if not pooled:
            return cls(ideal=(0.0, F_T_FLOOR), nadir=REFERENCE_POINT)
        front = np.asarray(non_dominated(pooled), dtype=float)
        ideal, nadir = front.min(axis=0), front.max(axis=0)
        return cls(
            ideal=(float(ideal[0]), float(ideal[1])), nadir=(float(nadir[0]), float(nadir[1]))
        )

    def normalise(self, points: Sequence[Point]) -> np.ndarray:
        f = np.asarray(points, dtype=float).reshape(-1, 2)
        span_acc = self.nadir[0] - self.ideal[0]
        f_acc = (f[:, 0] - self.ideal[0]) / (span_acc if span_acc > 0 else 1.0)
        low, high = (np.log(max(v, F_T_FLOOR)) for v in (self.ideal[1], self.nadir[1]))
        span_t = high - low
        f_t = (np.log(np.maximum(f[:, 1], F_T_FLOOR)) - low) / (span_t if span_t > 0 else 1.0)
        return np.column_stack([f_acc, f_t])

    def hypervolume(self, points: Sequence[Point]) -> float:
        """The share of the box from the ideal to the reference point that `points` dominate."""
        finite = [p for p in points if math.isfinite(p[0]) and math.isfinite(p[1])]
        if not finite:
            return 0.0
        reference = np.full(2, 1.0 + MARGIN)
        return float(HV(ref_point=reference)(self.normalise(finite))) / float(reference.prod())

    def as_dict(self) -> dict[str, list[float]]:
        return {"ideal": list(self.ideal), "nadir": list(self.nadir)}


@dataclass
class Experiment:
    """Runs and cross-evaluations of one experiment, written under `out`."""

    out: Path
    evaluator: EvaluatorFactory
    on_progress: Callable[[str], None] = lambda _: None
    # Objectives of diverged episodes (front members flagged in front.csv, cross-evaluations):
    # penalties, never a bound of the normalisation.
    penalised: set[Point] = field(default_factory=set)
    parallel: int | None = None  # runs and cross-evaluations at once; None: all of them
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)

    def concurrently(self, tasks: Mapping[K, Callable[[], T]]) -> dict[K, T]:
        """Each task (a run, a run and its cross-evaluation), up to `parallel` at once, keyed in
        the order given whatever order they finish in: what is written from them does not
        depend on `parallel`. If one fails (or Ctrl-C stops the wait), the others stop at their
        next evaluation, and the error is raised once all are done; each run keeps its
        checkpoint and goes on when the experiment is run again.

        Several processes may share an experiment (the same command, the same --out, on one
        file system): a task whose run another process is running (RunBusy) is passed over, and
        done once this process has done every other, when that process lets the run go (a run
        whose process died is resumed here)."""
        first = self._at_once(
            {key: functools.partial(_unless_busy, task) for key, task in tasks.items()}
        )
        later = self._at_once(
            {
                key: functools.partial(self._when_free, tasks[key])
                for key, done in first.items()
                if done is _BUSY
            }
        )
        return {key: later[key] if key in later else first[key] for key in tasks}

    def _at_once(self, tasks: Mapping[K, Callable[[], T]]) -> dict[K, T]:
        width = min(self.parallel or len(tasks), len(tasks))
        if width <= 1:
            return {key: task() for key, task in tasks.items()}
        with ThreadPoolExecutor(width, thread_name_prefix="experiment") as pool:
            futures = {key: pool.submit(task) for key, task in tasks.items()}
            try:
                return {key: future.result() for key, future in futures.items()}
            except BaseException:
                self._stop.set()
                for future in futures.values():
                    future.cancel()
                wait(futures.values())
                raise

    def _when_free(self, task: Callable[[], T]) -> T:
        """`task`, once no other process is running its run."""
        while True:
            try:
                return task()
            except RunBusy as busy:
                self._progress(f"{busy.directory.name}: run by {busy.holder or 'another process'}")
                self._stop.wait(BUSY_POLL_SECONDS)

    def tune_many(self, plan: Mapping[str, RunConfig]) -> dict[str, RunRecord]:
        """Every run of `plan` (name → configuration), concurrently, in plan order."""
        return self.concurrently(
            {name: functools.partial(self.tune, name, config) for name, config in plan.items()}
        )

    def _progress(self, text: str) -> None:
        """A run's progress, and the point where a run stops when the experiment stops."""
        if self._stop.is_set():
            raise KeyboardInterrupt
        self.on_progress(text)

    def _penalise(self, points: Iterable[Point]) -> None:
        with self._lock:
            self.penalised.update(points)

    def tune(self, name: str, config: RunConfig, feedforward: bytes | None = None) -> RunRecord:
        """The run `name` of `config`: kept if finished, resumed if not, started if new.
        `feedforward`: the model file `config.feedforward` names, served to the farm."""
        directory = self.out / "runs" / name
        record = _read(directory) if (directory / CONFIG_JSON).exists() else None
        if record is not None and record.config != config:
            raise ValueError(f"{directory} holds a run of another configuration")
        # Finished means stopped and reported: a run killed between its last records and its
        # figures is opened again, which only draws them.
        if record is None or record.stopped is None or not (directory / REPORT_MD).exists():
            try:
                run = (
                    TuningRun.open(directory)
                    if record
                    else TuningRun.create(directory, config, feedforward)
                )
            except FileExistsError:  # another process created it since: it is running it
                raise RunBusy(directory, "") from None
            # Closed however it ends: a run that failed is resumed by this same process when
            # the experiment goes on.
            evaluating = serving(self.evaluator(f"{self.out.name}-{name}", directory), run.models())
            with run, evaluating as evaluator:
                run.run(
                    evaluator,
                    lambda step: self._progress(
                        f"{name}: generation {step.generation}, {step.evaluations} evaluations"
                    ),
                )
                run.baseline(evaluator)
                write_run_report(run)
            record = _read(directory)
        self._penalise(m.objectives for m in record.front if m.diverged)
        return record

    def evaluate(
        self,
        name: str,
        members: Sequence[FrontMember],
        trajectory: TrajectorySpec,
        config: RunConfig,
    ) -> list[Point]:
        """Objectives of `members` on another trajectory (simulated again)."""
        return self.evaluate_gains(name, [member.gains for member in members], trajectory, config)

    def evaluate_gains(
        self,
        name: str,
        gains: Sequence[PDGains],
        trajectory: TrajectorySpec,
        config: RunConfig,
    ) -> list[Point]:
        """Objectives of the controllers `gains` on `trajectory`, in order (simulated again): the
        two `config` names (the paper's f_acc and f_t unless it names others)."""
        directory = self.out / "cross" / name
        with self.evaluator(f"{self.out.name}-x-{name}", directory) as evaluator:
            evaluator.submit(
                {
                    f"m{index:03d}": EpisodeSpec(
                        gains=each,
                        trajectory=trajectory,
                        model=config.model,
                        objectives=config.objectives,
                    )
                    for index, each in enumerate(gains)
                }
            )
            found = {e.job_id: e for e in evaluator.results()}
        points = []
        for key in sorted(found):
            scores = found[key].scores
            point = scores.objectives if scores else NO_EPISODE
            if scores and scores.diverged:
                self._penalise([point])
            points.append(point)
        self._progress(f"{name}: {len(points)} controllers evaluated again")
        return points

    def normalisation(self, point_sets: Sequence[Sequence[Point]]) -> Normalisation:
        """The normalised space of one problem, from every front the experiment judged on it."""
        return Normalisation.of(point_sets, self.penalised)

    def write_results(self, rows: list[dict[str, object]]) -> None:
        write_atomically(self.out / "results.csv", results_csv(rows))

    def write_stats(self, rows: Sequence[stats.StatsRow]) -> None:
        write_atomically(self.out / STATS_CSV, stats.stats_csv(rows))

    def write_normalisation(self, normalisations: dict[str, Normalisation]) -> None:
        text = json.dumps({k: n.as_dict() for k, n in normalisations.items()}, indent=2) + "\n"
        write_atomically(self.out / NORMALISATION_JSON, text.encode())

    def write_report(
        self,
        title: str,
        base: RunConfig,
        reps: int,
        table: Sequence[str],
        verdict: str,
        figures: Sequence[str],
        normalisations: Mapping[str, Normalisation],
        populations: Sequence[int] = (),
        durations: Sequence[float] = (),
    ) -> None:
        """The experiment's report.md; `populations` and `durations`: what its runs used, when
        they are not the base configuration's one population and duration."""
        write_experiment_report(
            self.out / "report.md",
            title=title,
            setup=experiment_setup(
                base,
                reps,
                {k: (n.ideal, n.nadir) for k, n in normalisations.items()},
                populations=populations,
                durations=durations,
            ),
            table=table,
            verdict=verdict,
            figures=figures,
        )


def serving(
    evaluator: AbstractContextManager[Evaluator], models: Mapping[str, bytes]
) -> AbstractContextManager[Evaluator]:
    """`evaluator`, before its first job, told to serve the feed-forward model files `models`
    (by SHA-256) its jobs name: a FarmClient (whose model server answers from `models` whenever
    asked) or an InProcessEvaluator, which both take them so."""
    if models:
        evaluator.models.update(models)  # type: ignore[attr-defined]
    return evaluator


def _read(directory: Path) -> RunRecord:
    """A run of the experiment from its plain files; ValueError naming it if unreadable."""
    try:
        upgrade(directory)
        return read_run(directory)
    except (OSError, ValueError) as error:
        raise ValueError(f"{directory}: unreadable run ({one_line(error)})") from None


def non_dominated(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    return [points[index] for index in non_dominated_indices(np.asarray(points).reshape(-1, 2))]


def front_points(record: RunRecord) -> list[tuple[float, float]]:
    return [member.objectives for member in record.front]


def dominated_count(points: Sequence[Point], by: Sequence[Point]) -> int:
    """How many of `points` some point of `by` dominates (no worse in both, better in one)."""
    return sum(
        any(q[0] <= p[0] and q[1] <= p[1] and (q[0] < p[0] or q[1] < p[1]) for q in by)
        for p in points
    )


# --- verdicts shared by the experiments ----------------------------------------------------------


def step_comparisons(values: Mapping[T, Sequence[float]]) -> dict[tuple[T, T], stats.Comparison]:
    """Each setting against the next smaller one, in ascending order: (smaller, larger) → the
    larger's values compared with the smaller's."""
    ordered = sorted(values)
    return {
        (small, large): stats.compare(values[large], values[small])
        for small, large in itertools.pairwise(ordered)
    }


def level_from(gains: Sequence[float], ordered: Sequence[float]) -> float | None:
    """Where a measure levels off over the settings `ordered` (ascending), given the settings
    with a significant gain over the next smaller one: the largest of those (the first setting
    if there is none); None if that is the largest setting tried, where it still rises."""
    top = max(gains, default=ordered[0])
    return None if gains and top == ordered[-1] else top


@dataclass(frozen=True)
class LevelsOff:
    """Whether and where a measure levels off over ascending settings: `text` says it; `level`
    is the setting from which no consecutive step gains significantly (None when the data
    cannot say, or it still gains at the last setting: `rising`)."""

    text: str
    level: float | None
    rising: bool


def levels_off(
    steps: Mapping[tuple[Any, Any], stats.Comparison],
    reps: int,
    measure: str,
    setting: str,
    shown: Callable[[float], str] = "{:g}".format,
    higher_is_better: bool = True,
) -> LevelsOff:
    """The verdict on `steps` (step_comparisons of `measure` over the values of `setting`,
    e.g. "the hypervolume" over "population size"; `shown` writes one value)."""
    if not steps:
        return LevelsOff(f"One {setting} only: nothing to compare.", None, False)
    if not all(stats.decidable(result) for result in steps.values()):
        return LevelsOff(
            f"With {reps} repetitions per {setting} the tests cannot reach p < "
            f"{stats.ALPHA:g}: cannot decide whether or where {measure} levels off; more "
            "repetitions are needed.",
            None,
            False,
        )
    ordered = sorted({value for step in steps for value in step})
    gains = [
        large
        for (_, large), result in steps.items()
        if stats.better(result, higher_is_better) == "a"
    ]
    level = level_from(gains, ordered)
    said = measure[:1].upper() + measure[1:]
    if level is None:
        text = (
            f"{said} still gains significantly at the last {setting} tried "
            f"({shown(ordered[-1])}): it does not level off within these {setting}s."
        )
    elif gains:
        text = (
            f"{said} levels off from {setting} {shown(level)} (no significant gain between "
            f"consecutive {setting}s from there on)."
        )
    else:
        text = (
            f"{said} shows no significant gain between consecutive {setting}s: it levels off "
            f"from the first, {shown(level)}."
        )
    return LevelsOff(text, level, level is None)


# --- the report and the figures shared by the experiments --------------------------------------


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
        f"{base.termination_text}, {plant_text(base.model)}",
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
    verdict: str,
    figures: Sequence[str],
) -> None:
    """An experiment's report.md: how it was run, its table, its verdict and its figures."""
    lines = [
        f"# {title}",
        "",
        *[f"- {line}" for line in setup],
        "",
        *table,
        "",
        verdict,
        "",
        *[f"![{name}]({name})" for name in figures],
        "",
    ]
    write_atomically(Path(path), "\n".join(lines).encode())


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


def attainment_panel(
    axes: Any, conditions: Mapping[str, Sequence[Sequence[Point]]], title: str
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
        axes.step(
            [p[0] * 1000 for p in surface],
            [max(p[1], 1e-12) for p in surface],
            where="post",
            marker=".",
            label=f"{label} ({what})",
        )
    axes.set(xlabel="f_acc (mm)", ylabel="f_t ((N·m)²)", title=title)
    if drawn:
        axes.set_yscale("log")
        axes.legend(fontsize=7)
