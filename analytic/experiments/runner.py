"""The runner every experiment shares: its tuning runs and the cross-evaluations of their fronts.

An experiment is a set of tuning runs (one directory each under OUT/runs/, resumable: a finished
run is kept, an unfinished one resumed), with cross-evaluations of their fronts where the
experiment needs them, all at once (up to `Experiment.parallel`, each run with its own farm
study, so an experiment is as wide as the farm); then results.csv, stats.csv
(analytic.experiments.statistics: tests, effect sizes and confidence intervals behind every
finding), normalisation.json (analytic.experiments.normalisation), a figure and report.md
(analytic.experiments.report).

Each experiment is one module of this package (popsize, generic_vs_specific, speed, algorithms,
dataset_value, feedforward, sensitivity) owning its computation, its table and its figure,
declared by an `ExperimentSpec` named EXPERIMENT and found through the plug-in group
`gainfarm.experiments` (analytic.experiments.registry). The runs are read back from their
plain files (analytic.tuning.records), never from their checkpoints.
"""

import functools
import json
import threading
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.normalisation import NORMALISATION_JSON, Normalisation, Point
from gainfarm.analytic.experiments.report import experiment_setup, write_experiment_report
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import (
    CONFIG_JSON,
    REPORT_MD,
    FrontMember,
    RunRecord,
    read_run,
    results_csv,
)
from gainfarm.analytic.tuning.run import RunBusy, TuningRun, upgrade
from gainfarm.analytic.view.run_report import write_run_report
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.objectives import NO_EPISODE
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec
from gainfarm.schemas.wire import one_line

K = TypeVar("K", bound=Hashable)
T = TypeVar("T")

ALL_KINDS = (TrajectoryKind.spiral, TrajectoryKind.random, TrajectoryKind.pyramid)
STATS_CSV = "stats.csv"
BUSY_POLL_SECONDS = 2.0  # how often a run another process is running is looked at again
_BUSY = object()  # what a task whose run another process is running gives first

# An evaluator for one run or cross-evaluation: given the farm study name it may use and the
# directory its logs go to, a context manager (FarmClient, InProcessEvaluator).
EvaluatorFactory = Callable[[str, Path], AbstractContextManager[Evaluator]]


def _unless_busy(task: Callable[[], T]) -> T | object:
    """The task's result, or _BUSY if another process is running its run."""
    try:
        return task()
    except RunBusy:
        return _BUSY


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
                        plant=config.plant,
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
        findings: str,
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
            findings=findings,
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
