"""The paper's experiments, as reruns: population size, generic against specific controllers,
trajectory speed.

An experiment is a set of tuning runs (one directory each under OUT/runs/, resumable: a finished
run is kept, an unfinished one resumed), with cross-evaluations of their fronts where the
experiment needs them, all at once (up to `Experiment.parallel`, each run with its own study on
the farm, so an experiment is as wide as the farm); then results.csv, stats.csv
(analytic.statistics: tests, effect sizes and confidence intervals behind every verdict),
normalisation.json, a figure and report.md.

Hypervolumes within a study are taken in one normalised space per problem (one trajectory the
fronts are judged on): between the ideal and the nadir point of the pooled non-dominated front of
every front the study judged on that problem, f_acc linearly and f_t on a log scale (as
analytic.evolution.normalise does), against the reference point 1.1 × (nadir − ideal) beyond the
ideal, as a fraction of that box. Penalty points (NO_EPISODE, a diverged episode, any point with
a mean error of DIVERGED_TICK_ERROR or more) never set the ideal or the nadir, so the values
spread over the range where the controllers really differ. normalisation.json records the ideal
and the nadir of each problem.

This module computes; analytic.figures draws and analytic.reports words what it hands them. The
runs are read back from their plain files (analytic.records), never from their checkpoints.
"""

import functools
import itertools
import json
import math
import statistics
import threading
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

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
from gainfarm.analytic.view.figures import plot_generic_vs_specific, plot_popsize, plot_speed
from gainfarm.analytic.view.reports import (
    controllers_table,
    experiment_setup,
    popsize_table,
    speed_table,
    write_experiment_report,
)
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.files import write_atomically
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR, NO_EPISODE, balancing_weights
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec

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
    """Runs and cross-evaluations of one study, written under `out`."""

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

    def tune(self, name: str, config: RunConfig) -> RunRecord:
        """The run `name` of `config`: kept if finished, resumed if not, started if new."""
        directory = self.out / "runs" / name
        record = _read(directory) if (directory / CONFIG_JSON).exists() else None
        if record is not None and record.config != config:
            raise ValueError(f"{directory} holds a run of another configuration")
        # Finished means stopped and reported: a run killed between its last records and its
        # figures is opened again, which only draws them.
        if record is None or record.stopped is None or not (directory / REPORT_MD).exists():
            try:
                run = TuningRun.open(directory) if record else TuningRun.create(directory, config)
            except FileExistsError:  # another process created it since: it is running it
                raise RunBusy(directory, "") from None
            # Closed however it ends: a run that failed is resumed by this same process when
            # the experiment goes on.
            with run, self.evaluator(f"{self.out.name}-{name}", directory) as evaluator:
                run.run(
                    evaluator,
                    lambda step: self._progress(
                        f"{name}: generation {step.generation}, {step.evaluations} evaluations"
                    ),
                )
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
        """Objectives of the controllers `gains` on `trajectory`, in order (simulated again)."""
        directory = self.out / "cross" / name
        with self.evaluator(f"{self.out.name}-x-{name}", directory) as evaluator:
            evaluator.submit(
                {
                    f"m{index:03d}": EpisodeSpec(
                        gains=each, trajectory=trajectory, model=config.model
                    )
                    for index, each in enumerate(gains)
                }
            )
            found = {e.job_id: e for e in evaluator.results()}
        points = []
        for key in sorted(found):
            scores = found[key].scores
            point = (scores.f_acc, scores.f_t) if scores else NO_EPISODE
            if scores and scores.diverged:
                self._penalise([point])
            points.append(point)
        self._progress(f"{name}: {len(points)} controllers evaluated again")
        return points

    def normalisation(self, point_sets: Sequence[Sequence[Point]]) -> Normalisation:
        """The normalised space of one problem, from every front the study judged on it."""
        return Normalisation.of(point_sets, self.penalised)

    def write_results(self, rows: list[dict[str, object]]) -> None:
        write_atomically(self.out / "results.csv", results_csv(rows))

    def write_stats(self, rows: Sequence[stats.StatsRow]) -> None:
        write_atomically(self.out / STATS_CSV, stats.stats_csv(rows))

    def write_normalisation(self, normalisations: dict[str, Normalisation]) -> None:
        text = json.dumps({k: n.as_dict() for k, n in normalisations.items()}, indent=2) + "\n"
        write_atomically(self.out / NORMALISATION_JSON, text.encode())


def _read(directory: Path) -> RunRecord:
    """A run of the experiment from its plain files; ValueError naming it if unreadable."""
    try:
        upgrade(directory)
        return read_run(directory)
    except (OSError, ValueError) as error:
        raise ValueError(f"{directory}: unreadable run ({error})") from None


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


def default_points(
    experiment: Experiment, base: RunConfig, kinds: Sequence[TrajectoryKind]
) -> dict[TrajectoryKind, Point]:
    """The default gains' (f_acc, f_t) on each kind's trajectory (at the base's duration and
    plant), which the generic objective is balanced by; ValueError if one diverges, since a
    penalty is no scale to balance by."""
    duration = base.trajectories[0].duration
    evaluated = experiment.concurrently(
        {
            kind: functools.partial(
                experiment.evaluate_gains,
                f"default-gains-on-{kind.value}",
                [DEFAULT_GAINS],
                TrajectorySpec(kind=kind, duration=duration),
                base,
            )
            for kind in kinds
        }
    )
    points = {}
    for kind, [point] in evaluated.items():
        if is_penalty(point, experiment.penalised):
            raise ValueError(
                f"the default gains diverge on the {kind.value}: nothing to balance by"
            )
        points[kind] = point
    return points


def level_from(gains: Sequence[float], ordered: Sequence[float]) -> float | None:
    """Where a measure levels off over the settings `ordered` (ascending), given the settings
    with a significant gain over the next smaller one: the largest of those (the first setting
    if there is none); None if that is the largest setting tried, where it still rises."""
    top = max(gains, default=ordered[0])
    return None if gains and top == ordered[-1] else top


def generic_set(test: TrajectoryKind, duration: float) -> tuple[TrajectorySpec, ...]:
    """What the generic controller judged on `test` is tuned on: every other kind, never
    `test` itself."""
    return tuple(TrajectorySpec(kind=kind, duration=duration) for kind in ALL_KINDS if kind != test)


# --- the three experiments -------------------------------------------------------------------


def popsize(experiment: Experiment, base: RunConfig, sizes: Sequence[int], reps: int) -> None:
    """Evaluations to converge and final hypervolume, for each population size."""
    plan = {
        (size, rep): (f"pop{size}-rep{rep}", base.model_copy(update={"pop": size, "seed": rep}))
        for size in sizes
        for rep in range(reps)
    }
    tuned = experiment.tune_many(dict(plan.values()))
    runs = {key: tuned[name] for key, (name, _) in plan.items()}
    fronts = {key: front_points(run) for key, run in runs.items()}
    normalisation = experiment.normalisation(list(fronts.values()))
    experiment.write_normalisation({"all runs": normalisation})
    rows = [
        {
            "pop": size,
            "rep": rep,
            "seed": rep,
            "evaluations": run.evaluations,
            "hypervolume": normalisation.hypervolume(fronts[(size, rep)]),
            "wall_seconds": run.wall_seconds,
            "stopped": run.stopped,
        }
        for (size, rep), run in runs.items()
    ]
    experiment.write_results(rows)
    by_size = {size: [row for row in rows if row["pop"] == size] for size in sizes}
    hypervolumes = {s: [float(r["hypervolume"]) for r in by_size[s]] for s in sizes}
    evaluations = {s: [int(r["evaluations"]) for r in by_size[s]] for s in sizes}
    plot_popsize(
        experiment.out / "popsize.png",
        hypervolumes,
        evaluations,
        {s: [fronts[(s, rep)] for rep in range(reps)] for s in sizes},
    )
    medians = {
        s: (statistics.median(hypervolumes[s]), statistics.median(evaluations[s])) for s in sizes
    }
    # Each size against the next smaller one: does the larger population gain?
    ordered = sorted(sizes)
    steps = list(itertools.pairwise(ordered))
    compared = {
        (small, large): stats.compare(hypervolumes[large], hypervolumes[small])
        for small, large in steps
    }
    stats_rows = [
        stats.StatsRow("popsize", f"pop {large} vs pop {small}", "hypervolume", result)
        for (small, large), result in compared.items()
    ] + [
        stats.StatsRow(
            "popsize",
            f"pop {large} vs pop {small}",
            "evaluations",
            stats.compare(evaluations[large], evaluations[small]),
        )
        for small, large in steps
    ]
    experiment.write_stats(stats_rows)
    lines = [
        f"- pop {large} against pop {small}: "
        + stats.decide(result, f"pop {large}", f"pop {small}")
        for (small, large), result in compared.items()
    ]
    if not steps:
        finding = "One population size only: nothing to compare."
    elif not all(stats.decidable(result) for result in compared.values()):
        finding = (
            f"With {reps} repetitions per size the tests cannot reach p < {stats.ALPHA:g}: "
            "cannot decide where the hypervolume levels off; more repetitions are needed."
        )
    else:
        gains = [large for (small, large), r in compared.items() if stats.better(r) == "a"]
        levels_off = level_from(gains, ordered)
        if levels_off is None:
            finding = (
                f"The hypervolume still rises significantly at the largest population tried "
                f"({ordered[-1]}): it does not level off within these sizes. The paper found a "
                "population near 30 the best trade-off: weigh the gains above against the "
                "evaluations each size costs."
            )
        else:
            finding = (
                f"The hypervolume levels off from population {levels_off} (no significant gain "
                f"between consecutive sizes from there on). The paper found a population near "
                "30 the best trade-off: "
                + ("this holds here." if 20 <= levels_off <= 50 else "here it lies elsewhere.")
            )
    verdict = "\n".join(
        [finding, "", "Each size against the next smaller (two-sided, alpha 0.05):", *lines]
    )
    table = popsize_table(medians)
    _report(
        experiment,
        "Population size",
        base,
        reps,
        table,
        verdict,
        ["popsize.png"],
        {"all runs": normalisation},
        populations=sizes,
    )


def generic_vs_specific(
    experiment: Experiment,
    base: RunConfig,
    reps: int,
    kinds: Sequence[TrajectoryKind] = ALL_KINDS,
) -> None:
    """Held out: for each test trajectory in turn, a generic controller tuned on the other
    kinds (never the test one) against a specific one tuned on the test trajectory, both judged
    on it. The generic controller's objectives are the means over its trajectories, balanced
    (schemas.objectives.balancing_weights) so that each trajectory counts alike at the default
    gains: unweighted, a pyramid's f_t, 10-40 times a spiral's, would make up nearly all of it."""
    duration = base.trajectories[0].duration
    defaults = default_points(experiment, base, ALL_KINDS)  # every kind some generic set holds

    def judged_on(test: TrajectorySpec, name: str, config: RunConfig) -> list[Point]:
        """A run's front as judged on `test`: its own, or simulated again on it."""
        run = experiment.tune(name, config)
        if config.trajectories == (test,):
            return front_points(run)
        return experiment.evaluate(f"{name}-on-{test.kind.value}", run.front, test, base)

    tasks = {}
    for kind in kinds:
        test = TrajectorySpec(kind=kind, duration=duration)
        trained_on = generic_set(kind, duration)
        weights = balancing_weights([defaults[t.kind] for t in trained_on])
        for rep in range(reps):
            specific = base.model_copy(update={"trajectories": (test,), "seed": rep})
            generic = base.model_copy(
                update={"trajectories": trained_on, "objective_weights": weights, "seed": rep}
            )
            for controller, name, config in (
                ("specific", f"specific-{kind.value}-rep{rep}", specific),
                ("generic", f"generic-no-{kind.value}-rep{rep}", generic),
            ):
                tasks[(kind.value, controller, rep)] = functools.partial(
                    judged_on, test, name, config
                )
    judged = experiment.concurrently(tasks)
    fronts: dict[str, dict[str, list[list[Point]]]] = {
        kind.value: {
            controller: [judged[(kind.value, controller, rep)] for rep in range(reps)]
            for controller in ("generic", "specific")
        }
        for kind in kinds
    }
    normalisations = {
        kind: experiment.normalisation([p for sets in per_kind.values() for p in sets])
        for kind, per_kind in fronts.items()
    }
    experiment.write_normalisation({f"on {k}": n for k, n in normalisations.items()})
    rows = []
    for kind, per_kind in fronts.items():
        for controller, other in (("generic", "specific"), ("specific", "generic")):
            for rep, points in enumerate(per_kind[controller]):
                rows.append(
                    {
                        "test_trajectory": kind,
                        "controller": controller,
                        "rep": rep,
                        "seed": rep,
                        "hypervolume": normalisations[kind].hypervolume(points),
                        "best_f_acc": min(p[0] for p in points),
                        "points": len(points),
                        "dominated_by_other": dominated_count(points, per_kind[other][rep]),
                    }
                )
    experiment.write_results(rows)

    def values(kind: str, controller: str, column: str) -> list[float]:
        return [
            float(r[column])  # type: ignore[arg-type]
            for r in rows
            if r["test_trajectory"] == kind and r["controller"] == controller
        ]

    def dominated_shares(kind: str, controller: str) -> list[float]:
        """Per repetition, the share of `controller`'s points the other's front dominates."""
        return [
            d / n if n else 0.0
            for d, n in zip(
                values(kind, controller, "dominated_by_other"),
                values(kind, controller, "points"),
                strict=True,
            )
        ]

    stats_rows: list[stats.StatsRow] = []
    lines = []
    holds = dominates = 0
    for kind in fronts:
        result = stats.compare(
            values(kind, "specific", "hypervolume"), values(kind, "generic", "hypervolume")
        )
        accuracy = stats.compare(
            values(kind, "specific", "best_f_acc"), values(kind, "generic", "best_f_acc")
        )
        # The same repetition's two fronts, point against point: the share of the generic
        # points the specific front dominates, against the share of the specific ones the
        # generic front dominates (Wilcoxon signed-rank, paired by repetition).
        dominance = stats.compare(
            dominated_shares(kind, "generic"), dominated_shares(kind, "specific"), paired=True
        )
        stats_rows += [
            stats.StatsRow("generic-vs-specific", f"specific vs generic, on {kind}", metric, r)
            for metric, r in (
                ("hypervolume", result),
                ("best_f_acc", accuracy),
                ("dominated_share", dominance),
            )
        ]
        holds += stats.better(result) == "a"
        dominates += stats.better(dominance) == "a"
        generic_dominated = int(sum(values(kind, "generic", "dominated_by_other")))
        specific_dominated = int(sum(values(kind, "specific", "dominated_by_other")))
        lines.append(
            f"- on the {kind} (held out of the generic set): "
            + stats.decide(result, "the specific controller", "the generic one")
            + f". Specific points dominate {generic_dominated} of "
            f"{int(sum(values(kind, 'generic', 'points')))} generic points; generic points "
            f"dominate {specific_dominated} of {int(sum(values(kind, 'specific', 'points')))} "
            "specific points (each repetition against the same repetition). By dominance, "
            "paired by repetition: "
            + stats.decide(dominance, "the specific controller", "the generic one")
            + "."
        )
    verdict = "\n".join(
        [
            f"The paper found specific controllers better than generic ones: by hypervolume this "
            f"holds significantly on {holds} of {len(fronts)} held-out trajectories, by the "
            f"share of each other's points the fronts dominate on {dominates} of {len(fronts)}.",
            "",
            *lines,
            "",
            "The generic objective is the mean over the generic set of each trajectory's f_acc "
            "and f_t, weighted by the inverse of the default gains' values there, so that each "
            "trajectory counts alike at the default gains. The default gains scored "
            + "; ".join(
                f"{kind.value} {1e3 * f_acc:.1f} mm, f_t {f_t:.3g} (N·m)²"
                for kind, (f_acc, f_t) in defaults.items()
            )
            + ".",
        ]
    )
    experiment.write_stats(stats_rows)
    medians = {
        (kind, controller): statistics.median(values(kind, controller, "hypervolume"))
        for kind in fronts
        for controller in ("specific", "generic")
    }
    plot_generic_vs_specific(
        experiment.out / "generic-vs-specific.png",
        {
            kind: {c: values(kind, c, "hypervolume") for c in ("specific", "generic")}
            for kind in fronts
        },
        fronts,
    )
    _report(
        experiment,
        "Generic against specific controllers (held out)",
        base,
        reps,
        controllers_table(medians),
        verdict,
        ["generic-vs-specific.png"],
        {f"on {k}": n for k, n in normalisations.items()},
    )


def speed(experiment: Experiment, base: RunConfig, durations: Sequence[float], reps: int) -> None:
    """Tune on spirals of each duration; evaluate every tuned front on every duration."""
    spirals = {d: TrajectorySpec(kind=TrajectoryKind.spiral, duration=d) for d in durations}
    matrix: dict[tuple[float, float], list[list[Point]]] = {}
    errors: dict[tuple[float, float], list[float]] = {}

    def tuned_and_moved(tuned: float, rep: int) -> tuple[RunRecord, dict[float, list[Point]]]:
        """The run on the spiral of `tuned` s, and its front on every spiral."""
        name = f"spiral{tuned:g}s-rep{rep}"
        run = experiment.tune(
            name, base.model_copy(update={"trajectories": (spirals[tuned],), "seed": rep})
        )
        return run, {
            used: front_points(run)
            if used == tuned
            else experiment.evaluate(f"{name}-on{used:g}s", run.front, spirals[used], base)
            for used in durations
        }

    done = experiment.concurrently(
        {
            (rep, tuned): functools.partial(tuned_and_moved, tuned, rep)
            for rep in range(reps)
            for tuned in durations
        }
    )
    for (_, tuned), (run, on) in done.items():
        members = run.front
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
    plot_speed(experiment.out / "speed.png", durations, hv, error, matrix)
    ordered = sorted(durations)
    own = {d: error[(d, d)] for d in durations}
    # Accuracy on its own spiral, each duration against the next shorter one (lower is better).
    steps = list(itertools.pairwise(ordered))
    falls = {
        (fast, slow): stats.compare(errors[(slow, slow)], errors[(fast, fast)])
        for fast, slow in steps
    }
    stats_rows = [
        stats.StatsRow("speed", f"{slow:g} s vs {fast:g} s, own spiral", "error_m", result)
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
            stats.StatsRow("speed", comparison, "error_m", err),
            stats.StatsRow("speed", comparison, "hypervolume", hyper),
        ]
    experiment.write_stats(stats_rows)
    on_own = ", ".join(f"{own[d] * 1000:.2f} mm at {d:g} s" for d in ordered)
    lines = [
        f"- {slow:g} s against {fast:g} s, own spiral: "
        + stats.decide(result, f"{slow:g} s", f"{fast:g} s", higher_is_better=False)
        for (fast, slow), result in falls.items()
    ]
    if not steps:
        finding = "One duration only: nothing to compare."
    elif not all(stats.decidable(r) for r in falls.values()):
        finding = (
            f"With {reps} repetitions per duration the tests cannot reach p < {stats.ALPHA:g}: "
            "cannot decide whether or where accuracy levels off; more repetitions are needed."
        )
    else:
        gains = [slow for (fast, slow), r in falls.items() if stats.better(r, False) == "a"]
        if gains and level_from(gains, ordered) is None:
            finding = (
                f"Accuracy still improves significantly at the slowest spiral tried "
                f"({max(gains):g} s): it does not level off within these durations."
            )
        elif gains:
            finding = (
                f"Accuracy improves significantly on slower spirals and levels off from "
                f"{max(gains):g} s (no significant gain between consecutive durations from there "
                "on)."
            )
        else:
            finding = "Accuracy shows no significant change between consecutive durations."
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
    _report(
        experiment,
        "Trajectory speed",
        base,
        reps,
        speed_table(durations, error),
        "\n".join(verdict_lines),
        ["speed.png"],
        {f"on {u:g} s": n for u, n in normalisations.items()},
        durations=durations,
    )


def _report(
    experiment: Experiment,
    title: str,
    base: RunConfig,
    reps: int,
    table: list[str],
    verdict: str,
    figures: list[str],
    normalisations: dict[str, Normalisation],
    populations: Sequence[int] = (),
    durations: Sequence[float] = (),
) -> None:
    """The experiment's report.md; `populations` and `durations`: what its runs used, when they
    are not the base configuration's one population and duration."""
    write_experiment_report(
        experiment.out / "report.md",
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
