"""The paper's generic-against-specific experiment, held out: for each test trajectory kind in
turn, a generic controller tuned on the other kinds (never the test one) against a specific one
tuned on the test trajectory, both judged on it, `reps` runs each (seed = rep).

Each test trajectory is a problem of its own ("on spiral", ...: normalisation.json's keys).
Written: results.csv (a row per run and test trajectory), stats.csv, normalisation.json,
generic-vs-specific.png and report.md.
"""

import functools
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.base import (
    ALL_KINDS,
    Experiment,
    ExperimentSpec,
    Point,
    attainment_panel,
    dominated_count,
    front_points,
    is_penalty,
    markdown_table,
)
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.objectives import balancing_weights
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec

NAME = "generic-vs-specific"
FIGURE = "generic-vs-specific.png"


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


def generic_set(test: TrajectoryKind, duration: float) -> tuple[TrajectorySpec, ...]:
    """What the generic controller judged on `test` is tuned on: every other kind, never
    `test` itself."""
    return tuple(TrajectorySpec(kind=kind, duration=duration) for kind in ALL_KINDS if kind != test)


def run(
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
        record = experiment.tune(name, config)
        if config.trajectories == (test,):
            return front_points(record)
        return experiment.evaluate(f"{name}-on-{test.kind}", record.front, test, base)

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
            stats.StatsRow(NAME, f"specific vs generic, on {kind}", metric, r)
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
    figure(
        experiment.out / FIGURE,
        {
            kind: {c: values(kind, c, "hypervolume") for c in ("specific", "generic")}
            for kind in fronts
        },
        fronts,
    )
    experiment.write_report(
        "Generic against specific controllers (held out)",
        base,
        reps,
        table(medians),
        verdict,
        [FIGURE],
        {f"on {k}": n for k, n in normalisations.items()},
    )


def table(medians: Mapping[tuple[str, str], float]) -> list[str]:
    """(test trajectory, kind of controller) → median hypervolume on that trajectory."""
    kinds = list(dict.fromkeys(kind for kind, _ in medians))
    controllers = list(dict.fromkeys(controller for _, controller in medians))
    return markdown_table(
        ["judged on", *(f"{c} median hypervolume" for c in controllers)],
        ([kind, *(f"{medians[(kind, c)]:.4f}" for c in controllers)] for kind in kinds),
    )


def figure(
    path: Path,
    hypervolumes: Mapping[str, Mapping[str, list[float]]],
    fronts: Mapping[str, Mapping[str, list[list[Point]]]],
) -> None:
    """Per held-out test trajectory (a column each): hypervolume box plots per kind of
    controller on top, their median attainment surfaces on that trajectory below."""
    kinds = list(hypervolumes)
    canvas = new_figure((4.5 * max(1, len(kinds)), 8))
    panels = canvas.subplots(2, max(1, len(kinds)), squeeze=False)
    for column, kind in enumerate(kinds):
        top, bottom = panels[0][column], panels[1][column]
        top.boxplot(list(hypervolumes[kind].values()), tick_labels=list(hypervolumes[kind]))
        top.set(ylabel=f"hypervolume on the {kind}", title=f"judged on the {kind} (held out)")
        attainment_panel(bottom, fronts.get(kind, {}), f"fronts on the {kind}")
    save_png(canvas, path)


EXPERIMENT = ExperimentSpec(
    name=NAME,
    summary="the paper's generic against specific controllers, each trajectory held out in turn",
    run=run,
    trajectories=lambda base, _options: [
        TrajectorySpec(kind=kind, duration=base.trajectories[0].duration) for kind in ALL_KINDS
    ],
)
