"""The paper's experiments, as reruns: population size, generic against specific controllers,
trajectory speed.

An experiment is a set of tuning runs (one directory each under OUT/runs/, resumable: a finished
run is kept, an unfinished one resumed), then cross-evaluations of their fronts where the
experiment needs them, then results.csv, a figure and report.md. Within an experiment every
hypervolume uses one common reference point, as the paper does: the worst f_acc and f_t among all
controllers the experiment tested (runs and cross-evaluations; candidates with no episode left
out), in the same normalised space as a run's (f_t on a log scale).

This module computes; analytic.figures draws and analytic.reports words what it hands them. The
runs are read back from their plain files (analytic.records), never from their checkpoints.
"""

import statistics
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analytic.config import RunConfig
from analytic.evaluator import Evaluator
from analytic.evolution import hypervolume, non_dominated_indices
from analytic.figures import plot_generic_vs_specific, plot_popsize, plot_speed
from analytic.records import (
    CONFIG_JSON,
    REPORT_MD,
    FrontMember,
    RunRecord,
    read_run,
    results_csv,
)
from analytic.reports import (
    controllers_table,
    experiment_setup,
    popsize_table,
    speed_table,
    write_experiment_report,
)
from analytic.run import TuningRun, upgrade
from schemas.episode import EpisodeSpec
from schemas.files import write_atomically
from schemas.objectives import NO_EPISODE
from schemas.trajectory import TrajectoryKind, TrajectorySpec

ALL_KINDS = (TrajectoryKind.spiral, TrajectoryKind.random, TrajectoryKind.pyramid)

# An evaluator for one run or cross-evaluation: given the farm study name it may use and the
# directory its logs go to, a context manager (FarmClient, InProcessEvaluator).
EvaluatorFactory = Callable[[str, Path], AbstractContextManager[Evaluator]]


@dataclass
class Experiment:
    """Runs and cross-evaluations with a common reference point, written under `out`."""

    out: Path
    evaluator: EvaluatorFactory
    on_progress: Callable[[str], None] = lambda _: None
    tested: list[tuple[float, float]] = field(default_factory=list)

    def tune(self, name: str, config: RunConfig) -> RunRecord:
        """The run `name` of `config`: kept if finished, resumed if not, started if new."""
        directory = self.out / "runs" / name
        record = _read(directory) if (directory / CONFIG_JSON).exists() else None
        if record is not None and record.config != config:
            raise ValueError(f"{directory} holds a run of another configuration")
        # Finished means stopped and reported: a run killed between its last records and its
        # figures is opened again, which only draws them.
        if record is None or record.stopped is None or not (directory / REPORT_MD).exists():
            run = TuningRun.open(directory) if record else TuningRun.create(directory, config)
            with self.evaluator(f"{self.out.name}-{name}", directory) as evaluator:
                run.run(
                    evaluator,
                    lambda step: self.on_progress(
                        f"{name}: generation {step.generation}, {step.evaluations} evaluations"
                    ),
                )
            record = _read(directory)
        self.tested += [point for point in record.evaluated if point != NO_EPISODE]
        return record

    def evaluate(
        self,
        name: str,
        members: Sequence[FrontMember],
        trajectory: TrajectorySpec,
        config: RunConfig,
    ) -> list[tuple[float, float]]:
        """Objectives of `members` on another trajectory (simulated again)."""
        directory = self.out / "cross" / name
        with self.evaluator(f"{self.out.name}-x-{name}", directory) as evaluator:
            evaluator.submit(
                {
                    f"m{index:03d}": EpisodeSpec(
                        gains=member.gains, trajectory=trajectory, model=config.model
                    )
                    for index, member in enumerate(members)
                }
            )
            found = {e.job_id: e for e in evaluator.results()}
        points = [
            (found[key].scores.f_acc, found[key].scores.f_t) if found[key].scores else NO_EPISODE
            for key in sorted(found)
        ]
        self.tested += [point for point in points if point != NO_EPISODE]
        self.on_progress(f"{name}: {len(points)} controllers evaluated again")
        return points

    @property
    def reference(self) -> tuple[float, float]:
        return (max(p[0] for p in self.tested), max(p[1] for p in self.tested))

    def hypervolume(self, points: Sequence[tuple[float, float]]) -> float:
        return hypervolume(non_dominated(points), self.reference)

    def write_results(self, rows: list[dict[str, object]]) -> None:
        write_atomically(self.out / "results.csv", results_csv(rows))


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


# --- the three experiments -------------------------------------------------------------------


def popsize(experiment: Experiment, base: RunConfig, sizes: Sequence[int], reps: int) -> None:
    """Evaluations to converge and final hypervolume, for each population size."""
    runs = {
        (size, rep): experiment.tune(
            f"pop{size}-rep{rep}", base.model_copy(update={"pop": size, "seed": rep})
        )
        for size in sizes
        for rep in range(reps)
    }
    rows = [
        {
            "pop": size,
            "rep": rep,
            "seed": rep,
            "evaluations": run.evaluations,
            "hypervolume": experiment.hypervolume(front_points(run)),
            "wall_seconds": run.wall_seconds,
            "stopped": run.stopped,
        }
        for (size, rep), run in runs.items()
    ]
    experiment.write_results(rows)
    by_size = {size: [row for row in rows if row["pop"] == size] for size in sizes}
    hypervolumes = {s: [r["hypervolume"] for r in by_size[s]] for s in sizes}
    evaluations = {s: [r["evaluations"] for r in by_size[s]] for s in sizes}
    plot_popsize(experiment.out / "popsize.png", hypervolumes, evaluations)
    medians = {
        s: (statistics.median(hypervolumes[s]), statistics.median(evaluations[s])) for s in sizes
    }
    best_hv = max(sizes, key=lambda s: medians[s][0])
    # The trade-off: the smallest population whose median hypervolume is within 1 % of the best.
    trade_off = min(s for s in sizes if medians[s][0] >= 0.99 * medians[best_hv][0])
    table = popsize_table(medians)
    verdict = (
        f"The best median hypervolume comes with population {best_hv}; the smallest population "
        f"within 1 % of it is {trade_off}, at a median of {medians[trade_off][1]:.0f} "
        f"evaluations. The paper found a population near 30 the best trade-off: "
        + ("this holds here." if 20 <= trade_off <= 50 else "here the trade-off lies elsewhere.")
    )
    _report(experiment, "Population size", base, reps, table, verdict, ["popsize.png"])


def generic_vs_specific(experiment: Experiment, base: RunConfig, reps: int) -> None:
    """A generic controller (all trajectories) against a specific one (the pyramid), both
    evaluated on the pyramid."""
    duration = base.trajectories[0].duration
    pyramid = TrajectorySpec(kind=TrajectoryKind.pyramid, duration=duration)
    generic_set = tuple(TrajectorySpec(kind=kind, duration=duration) for kind in ALL_KINDS)
    fronts: dict[str, list[list[tuple[float, float]]]] = {"generic": [], "specific": []}
    for rep in range(reps):
        specific = experiment.tune(
            f"specific-rep{rep}", base.model_copy(update={"trajectories": (pyramid,), "seed": rep})
        )
        generic = experiment.tune(
            f"generic-rep{rep}", base.model_copy(update={"trajectories": generic_set, "seed": rep})
        )
        fronts["specific"].append(front_points(specific))
        fronts["generic"].append(
            experiment.evaluate(f"generic-rep{rep}", generic.front, pyramid, base)
        )
    rows = [
        {
            "controller": kind,
            "rep": rep,
            "seed": rep,
            "hypervolume_on_pyramid": experiment.hypervolume(points),
            "best_f_acc": min(p[0] for p in points),
        }
        for kind, per_rep in fronts.items()
        for rep, points in enumerate(per_rep)
    ]
    experiment.write_results(rows)
    values = {
        kind: [r["hypervolume_on_pyramid"] for r in rows if r["controller"] == kind]
        for kind in fronts
    }
    plot_generic_vs_specific(
        experiment.out / "generic-vs-specific.png",
        values,
        {kind: sorted(non_dominated(fronts[kind][0])) for kind in ("specific", "generic")},
    )
    median = {kind: statistics.median(values[kind]) for kind in fronts}
    table = controllers_table(median)
    lead = median["specific"] - median["generic"]
    spread = max((statistics.stdev(v) for v in values.values() if len(v) > 1), default=0.0)
    if lead > spread:
        finding = "this holds here"
    elif lead < -spread:
        finding = "here the generic one is better"
    else:
        finding = (
            f"here the difference ({lead:+.4f}) is within the spread between repetitions "
            f"(standard deviation up to {spread:.4f}): the two are on a par"
        )
    verdict = (
        f"On the pyramid, the specific controller's median hypervolume is "
        f"{median['specific']:.4f} and the generic one's {median['generic']:.4f}. The paper "
        f"found specific controllers better: {finding}."
    )
    _report(
        experiment,
        "Generic against specific controllers",
        base,
        reps,
        table,
        verdict,
        ["generic-vs-specific.png"],
    )


def speed(experiment: Experiment, base: RunConfig, durations: Sequence[float], reps: int) -> None:
    """Tune on spirals of each duration; evaluate every tuned front on every duration."""
    spirals = {d: TrajectorySpec(kind=TrajectoryKind.spiral, duration=d) for d in durations}
    matrix: dict[tuple[float, float], list[list[tuple[float, float]]]] = {}
    errors: dict[tuple[float, float], list[float]] = {}
    for rep in range(reps):
        for tuned in durations:
            run = experiment.tune(
                f"spiral{tuned:g}s-rep{rep}",
                base.model_copy(update={"trajectories": (spirals[tuned],), "seed": rep}),
            )
            members = run.front
            for used in durations:
                points = (
                    front_points(run)
                    if used == tuned
                    else experiment.evaluate(
                        f"spiral{tuned:g}s-rep{rep}-on{used:g}s", members, spirals[used], base
                    )
                )
                matrix.setdefault((tuned, used), []).append(points)
                # The most accurate controller (on its own trajectory) and its error on `used`.
                most_accurate = min(range(len(members)), key=lambda i: members[i].f_acc)
                errors.setdefault((tuned, used), []).append(points[most_accurate][0])
    hv = {
        key: statistics.median(experiment.hypervolume(p) for p in value)
        for key, value in matrix.items()
    }
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
    plot_speed(experiment.out / "speed.png", durations, hv, error)
    own = {d: error[(d, d)] for d in durations}
    transfer = [error[(t, u)] / own[u] - 1 for t in durations for u in durations if t != u]
    table = speed_table(durations, error)
    ordered = sorted(durations)
    on_own = ", ".join(f"{own[d] * 1000:.2f} mm at {d:g} s" for d in ordered)
    gain = own[ordered[0]] - own[ordered[-1]]
    if gain > 0:
        # Where the error comes within 10 % of the whole gain of its best value: the plateau.
        best = min(own.values())
        plateau = next(d for d in ordered if own[d] - best <= 0.1 * gain)
        finding = f"falls on faster trajectories and levels off from {plateau:g} s"
    else:
        finding = "does not fall on faster trajectories"
    verdict = (
        f"The most accurate controller's error on its own spiral: {on_own}. Accuracy "
        f"{finding} (the paper: it falls, and levels off near 5 s)."
    )
    if transfer:
        cost = statistics.median(transfer)
        verdict += (
            f" Run at another speed, it changes its error by a median of {cost:+.0%} against "
            "the controller tuned for that speed (the paper: moving a controller to another "
            f"speed costs little{': this holds here' if cost < 0.25 else ': not so here'})."
        )
    _report(experiment, "Trajectory speed", base, reps, table, verdict, ["speed.png"])


def _report(
    experiment: Experiment,
    title: str,
    base: RunConfig,
    reps: int,
    table: list[str],
    verdict: str,
    figures: list[str],
) -> None:
    write_experiment_report(
        experiment.out / "report.md",
        title=title,
        setup=experiment_setup(base, reps, experiment.reference),
        table=table,
        verdict=verdict,
        figures=figures,
    )
