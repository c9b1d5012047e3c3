"""The paper's studies, as reruns on the farm: population size, generic against specific
controllers, trajectory speed.

A study is a set of tuning runs (one directory each under OUT/runs/, resumable: a finished run is
kept, an unfinished one resumed), then cross-evaluations of their fronts where the study needs
them, then results.csv, figures and report.md. Within a study every hypervolume uses one common
reference point, as the paper does: the worst f_acc and f_t among all controllers the study tested
(runs and cross-evaluations; candidates with no episode left out), in the same normalised space as
a run's (f_t on a log scale).
"""

import csv
import io
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from analytic.evolution import NO_EPISODE, Candidate, hypervolume, non_dominated_indices
from analytic.farm import FarmClient
from analytic.figures import save_png
from analytic.run import RunConfig, TuningRun
from schemas.episode import EpisodeSpec
from schemas.files import write_atomically
from schemas.security import TlsIdentity
from schemas.trajectory import TrajectoryKind, TrajectorySpec

ALL_KINDS = (TrajectoryKind.spiral, TrajectoryKind.random, TrajectoryKind.pyramid)


@dataclass
class Study:
    """Runs and cross-evaluations on one farm, with a common reference point."""

    out: Path
    endpoints: list[str]
    on_progress: Callable[[str], None] = lambda _: None
    identity: TlsIdentity | None = None  # the analytic credentials of a secure farm
    tested: list[tuple[float, float]] = field(default_factory=list)

    def tune(self, name: str, config: RunConfig) -> TuningRun:
        directory = self.out / "runs" / name
        run = (
            TuningRun.open(directory) if directory.exists() else TuningRun.create(directory, config)
        )
        if run.config != config:
            raise ValueError(f"{directory} holds a run of another configuration")
        if not run.finished:
            with FarmClient(
                self.endpoints, f"{self.out.name}-{name}", directory, identity=self.identity
            ) as farm:
                run.run(
                    farm,
                    lambda step: self.on_progress(
                        f"{name}: generation {step.generation}, {step.evaluations} evaluations"
                    ),
                )
        self.tested += [point for point in run.state.evaluated if point != NO_EPISODE]
        return run

    def evaluate(
        self, name: str, members: Sequence[Candidate], trajectory: TrajectorySpec, config: RunConfig
    ) -> list[tuple[float, float]]:
        """Objectives of `members` on another trajectory (the farm simulates them again)."""
        directory = self.out / "cross" / name
        with FarmClient(
            self.endpoints, f"{self.out.name}-x-{name}", directory, identity=self.identity
        ) as farm:
            farm.submit(
                {
                    f"m{index:03d}": EpisodeSpec(
                        gains=member.gains, trajectory=trajectory, model=config.model
                    )
                    for index, member in enumerate(members)
                }
            )
            found = {e.job_id: e for e in farm.results()}
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


def non_dominated(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    return [points[index] for index in non_dominated_indices(np.asarray(points).reshape(-1, 2))]


def front_points(run: TuningRun) -> list[tuple[float, float]]:
    return [member.objectives for member in run.state.evolution.front()]


# --- the three studies ---------------------------------------------------------------------


def popsize(study: Study, base: RunConfig, sizes: Sequence[int], reps: int) -> None:
    """Evaluations to converge and final hypervolume, for each population size."""
    runs = {
        (size, rep): study.tune(
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
            "evaluations": run.state.evolution.evaluations,
            "hypervolume": study.hypervolume(front_points(run)),
            "wall_seconds": run.state.wall_seconds,
            "stopped": run.state.stopped,
        }
        for (size, rep), run in runs.items()
    ]
    _write_csv(study.out / "results.csv", rows)
    by_size = {size: [row for row in rows if row["pop"] == size] for size in sizes}
    figure = Figure(figsize=(10, 4))
    left, right = figure.subplots(1, 2)
    labels = [str(size) for size in sizes]
    left.boxplot([[r["hypervolume"] for r in by_size[s]] for s in sizes], tick_labels=labels)
    left.set(
        xlabel="population size", ylabel="hypervolume (study reference)", title="final hypervolume"
    )
    right.boxplot([[r["evaluations"] for r in by_size[s]] for s in sizes], tick_labels=labels)
    right.set(xlabel="population size", ylabel="evaluations", title="evaluations to stop")
    figure.tight_layout()
    save_png(figure, study.out / "popsize.png")
    medians = {
        s: (
            statistics.median(r["hypervolume"] for r in by_size[s]),
            statistics.median(r["evaluations"] for r in by_size[s]),
        )
        for s in sizes
    }
    best_hv = max(sizes, key=lambda s: medians[s][0])
    # The trade-off: the smallest population whose median hypervolume is within 1 % of the best.
    trade_off = min(s for s in sizes if medians[s][0] >= 0.99 * medians[best_hv][0])
    table = ["| population | median hypervolume | median evaluations |", "|---:|---:|---:|"]
    table += [f"| {s} | {medians[s][0]:.4f} | {medians[s][1]:.0f} |" for s in sizes]
    verdict = (
        f"The best median hypervolume comes with population {best_hv}; the smallest population "
        f"within 1 % of it is {trade_off}, at a median of {medians[trade_off][1]:.0f} "
        f"evaluations. The paper found a population near 30 the best trade-off: "
        + ("this holds here." if 20 <= trade_off <= 50 else "here the trade-off lies elsewhere.")
    )
    _report(study, "Population size", base, reps, table, verdict, ["popsize.png"])


def generic_vs_specific(study: Study, base: RunConfig, reps: int) -> None:
    """A generic controller (all trajectories) against a specific one (the pyramid), both
    evaluated on the pyramid."""
    duration = base.trajectories[0].duration
    pyramid = TrajectorySpec(kind=TrajectoryKind.pyramid, duration=duration)
    generic_set = tuple(TrajectorySpec(kind=kind, duration=duration) for kind in ALL_KINDS)
    fronts: dict[str, list[list[tuple[float, float]]]] = {"generic": [], "specific": []}
    for rep in range(reps):
        specific = study.tune(
            f"specific-rep{rep}", base.model_copy(update={"trajectories": (pyramid,), "seed": rep})
        )
        generic = study.tune(
            f"generic-rep{rep}", base.model_copy(update={"trajectories": generic_set, "seed": rep})
        )
        fronts["specific"].append(front_points(specific))
        members = generic.state.evolution.front()
        fronts["generic"].append(study.evaluate(f"generic-rep{rep}", members, pyramid, base))
    rows = [
        {
            "controller": kind,
            "rep": rep,
            "seed": rep,
            "hypervolume_on_pyramid": study.hypervolume(points),
            "best_f_acc": min(p[0] for p in points),
        }
        for kind, per_rep in fronts.items()
        for rep, points in enumerate(per_rep)
    ]
    _write_csv(study.out / "results.csv", rows)
    figure = Figure(figsize=(10, 4))
    left, right = figure.subplots(1, 2)
    left.boxplot(
        [[r["hypervolume_on_pyramid"] for r in rows if r["controller"] == kind] for kind in fronts],
        tick_labels=list(fronts),
    )
    left.set(ylabel="hypervolume on the pyramid", title="hypervolume")
    for kind, marker in (("specific", "o"), ("generic", "s")):
        points = sorted(non_dominated(fronts[kind][0]))
        right.plot(
            [p[0] * 1000 for p in points],
            [p[1] for p in points],
            marker=marker,
            label=f"{kind} (rep 0)",
        )
    right.set(
        xlabel="f_acc (mm)", ylabel="f_t ((N·m)²)", yscale="log", title="fronts on the pyramid"
    )
    right.legend()
    figure.tight_layout()
    save_png(figure, study.out / "generic-vs-specific.png")
    values = {
        kind: [r["hypervolume_on_pyramid"] for r in rows if r["controller"] == kind]
        for kind in fronts
    }
    median = {kind: statistics.median(values[kind]) for kind in fronts}
    table = ["| controller | median hypervolume on the pyramid |", "|---|---:|"]
    table += [f"| {kind} | {median[kind]:.4f} |" for kind in fronts]
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
        study,
        "Generic against specific controllers",
        base,
        reps,
        table,
        verdict,
        ["generic-vs-specific.png"],
    )


def speed(study: Study, base: RunConfig, durations: Sequence[float], reps: int) -> None:
    """Tune on spirals of each duration; evaluate every tuned front on every duration."""
    spirals = {d: TrajectorySpec(kind=TrajectoryKind.spiral, duration=d) for d in durations}
    matrix: dict[tuple[float, float], list[list[tuple[float, float]]]] = {}
    errors: dict[tuple[float, float], list[float]] = {}
    for rep in range(reps):
        for tuned in durations:
            run = study.tune(
                f"spiral{tuned:g}s-rep{rep}",
                base.model_copy(update={"trajectories": (spirals[tuned],), "seed": rep}),
            )
            members = run.state.evolution.front()
            for used in durations:
                points = (
                    front_points(run)
                    if used == tuned
                    else study.evaluate(
                        f"spiral{tuned:g}s-rep{rep}-on{used:g}s", members, spirals[used], base
                    )
                )
                matrix.setdefault((tuned, used), []).append(points)
                # The most accurate controller (on its own trajectory) and its error on `used`.
                most_accurate = min(range(len(members)), key=lambda i: members[i].objectives[0])
                errors.setdefault((tuned, used), []).append(points[most_accurate][0])
    hv = {
        key: statistics.median(study.hypervolume(p) for p in value) for key, value in matrix.items()
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
    _write_csv(study.out / "results.csv", rows)
    figure = Figure(figsize=(10, 4.5))
    left, right = figure.subplots(1, 2)
    for axes, values, title, fmt in (
        (left, hv, "median hypervolume", "{:.3f}"),
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
                axes.text(j, i, fmt.format(value), ha="center", va="center", color="white")
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
    figure.tight_layout()
    save_png(figure, study.out / "speed.png")
    own = {d: error[(d, d)] for d in durations}
    transfer = [error[(t, u)] / own[u] - 1 for t in durations for u in durations if t != u]
    table = [
        "| tuned on | " + " | ".join(f"on {d:g} s" for d in durations) + " |",
        "|---|" + "---:|" * len(durations),
    ]
    table += [
        f"| {t:g} s | " + " | ".join(f"{error[(t, u)] * 1000:.2f} mm" for u in durations) + " |"
        for t in durations
    ]
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
    _report(study, "Trajectory speed", base, reps, table, verdict, ["speed.png"])


# --- writing -----------------------------------------------------------------------------


def _write_csv(path: Path, rows: list[dict[str, object]]) -> None:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    write_atomically(path, buffer.getvalue().encode())


def _report(
    study: Study,
    title: str,
    base: RunConfig,
    reps: int,
    table: list[str],
    verdict: str,
    figures: list[str],
) -> None:
    reference = study.reference
    lines = [
        f"# {title}",
        "",
        f"- {reps} repetitions (seeds 0..{reps - 1}); base configuration: population "
        f"{base.pop}, {base.termination_text}, {base.model.joints} joints",
        f"- common reference point: f_acc {reference[0]:.4g} m, f_t {reference[1]:.4g} (N·m)² "
        "(the worst among all controllers tested in this study)",
        "- runs in `runs/`, raw numbers in `results.csv`",
        "",
        *table,
        "",
        verdict,
        "",
        *[f"![{name}]({name})" for name in figures],
        "",
    ]
    write_atomically(study.out / "report.md", "\n".join(lines).encode())
