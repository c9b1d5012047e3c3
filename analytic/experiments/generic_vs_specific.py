"""The paper's generic-against-specific experiment, in two designs, each asking its own question:

- paper: is a controller tuned on the test trajectory alone better than one tuned on every
  trajectory, the test one included (the paper's generic controller)?
- held-out: does a controller transfer to a path it never saw? For each test trajectory in turn,
  a generic controller tuned on the other kinds against the specific one (a specialist beating
  it is expected; the question is by how much).

`reps` runs (seed = rep) of each: a specific controller per test trajectory (shared by both
designs), one generic controller on every kind (paper), and one per test trajectory on the other
kinds (held out). Generic fronts are simulated again on each test trajectory they are judged on.

Preregistered: the repetitions, the designs and the test trajectories are written to
preregistration.json before the first run, and a directory is never resumed with others, so no
experiment is extended after its result is seen (optional stopping). The report's claims are the
hypervolume and the dominance test of each design on each test trajectory, Holm-adjusted as one
family. Beside them, effect sizes in physical units, estimated, not tested (specific − generic,
paired by repetition, 95 % bootstrap CI), as analytic.experiments.measures takes them: the error
at one torque smoothness every front judged on the test trajectory reaches (mm), and the
recommended controllers' error (mm) and f_t ((N·m)²) there.

Each test trajectory is a problem of its own ("on spiral", ...: normalisation.json's keys), its
space pooled over the fronts of both designs. Written: preregistration.json, results.csv (a row
per design, test trajectory, controller and repetition), stats.csv (raw p-values; the report's
are Holm-adjusted), normalisation.json, generic-vs-specific.png and report.md.
"""

import functools
import json
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from gainfarm.analytic.experiments import measures
from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.normalisation import (
    Normalisation,
    Point,
    dominated_count,
    front_points,
    is_penalty,
)
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option
from gainfarm.analytic.experiments.report import (
    attainment_panel,
    experiment_setup,
    markdown_table,
    write_experiment_report,
)
from gainfarm.analytic.experiments.runner import ALL_KINDS, Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.objectives import balancing_weights
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec

NAME = "generic-vs-specific"
FIGURE = "generic-vs-specific.png"
PREREGISTRATION_JSON = "preregistration.json"
PAPER, HELD_OUT = "paper", "held-out"
DESIGNS = (PAPER, HELD_OUT)
SPECIFIC, GENERIC = "specific", "generic"
QUESTIONS = {
    PAPER: "(a) The paper's design: is a controller tuned on the test trajectory alone better "
    "than one tuned on every trajectory, the test one included?",
    HELD_OUT: "(b) Held out: does a controller transfer to a path it never saw?",
}
GENERIC_LABELS = {PAPER: "generic (all)", HELD_OUT: "generic (held out)"}
LOG_NOTE = "f_t on a log scale in it, a choice the paper does not make"


@dataclass(frozen=True)
class Effect:
    """An effect size in physical units: how the report names it, its unit there, the factor
    from results.csv's unit (m, (N·m)²) to it, and its metric in stats.csv."""

    what: str
    unit: str
    scale: float
    metric: str


# results.csv's column → its effect, in the order the report gives them.
EFFECTS = {
    "error_at_level": Effect("error at one torque smoothness", "mm", 1e3, "error_at_level_mm"),
    "recommended_f_acc": Effect(
        "the recommended controllers' error", "mm", 1e3, "recommended_error_mm"
    ),
    "recommended_f_t": Effect("their f_t", "(N·m)²", 1.0, "recommended_f_t"),
}


def chosen_designs(text: str) -> tuple[str, ...]:
    """--design: paper, held-out or both (ValueError otherwise)."""
    if text == "both":
        return DESIGNS
    if text in DESIGNS:
        return (text,)
    raise ValueError(f"expected paper, held-out or both, got {text!r}")


def preregister(
    out: Path, reps: int, designs: Sequence[str], kinds: Sequence[TrajectoryKind]
) -> None:
    """Fix the repetitions, designs and test trajectories before the first run (in
    preregistration.json), or check that a resumed experiment keeps them: ValueError, naming the
    option, for a directory preregistered otherwise or holding runs from before any was."""
    plan = {"reps": reps, "designs": list(designs), "test_trajectories": [k.value for k in kinds]}
    path = out / PREREGISTRATION_JSON
    if not path.exists():
        if (out / "runs").exists():
            raise ValueError(
                f"--out: {out} holds runs started before their number was preregistered; "
                "start the experiment in a new --out"
            )
        out.mkdir(parents=True, exist_ok=True)
        write_atomically(path, (json.dumps(plan, indent=1) + "\n").encode())
        return
    try:
        fixed = json.loads(path.read_bytes())
    except (OSError, ValueError) as error:
        raise ValueError(f"--out: {path} is unreadable ({error})") from None
    for key, option in (
        ("reps", "--reps"),
        ("designs", "--design"),
        ("test_trajectories", "--out"),
    ):
        if not isinstance(fixed, dict) or fixed.get(key) != plan[key]:
            was = fixed.get(key) if isinstance(fixed, dict) else None
            raise ValueError(
                f"{option}: {out} was preregistered with {key.replace('_', ' ')} {was}, not "
                f"{plan[key]} ({PREREGISTRATION_JSON}); changing them once results are seen is "
                "optional stopping: start a new --out"
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
                [base.default_gains],
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
    """What the held-out generic controller judged on `test` is tuned on: every other kind,
    never `test` itself."""
    return tuple(TrajectorySpec(kind=kind, duration=duration) for kind in ALL_KINDS if kind != test)


@dataclass(frozen=True)
class Judged:
    """A run's front as judged on one test trajectory, and there its recommended member (or the
    closest to dominating the default gains, `pick`)."""

    points: list[Point]
    pick: str
    picked: Point


def run(
    experiment: Experiment,
    base: RunConfig,
    reps: int,
    kinds: Sequence[TrajectoryKind] = ALL_KINDS,
    designs: Sequence[str] = DESIGNS,
) -> None:
    """Both designs (or those of `designs`) on each test trajectory of `kinds`. A generic
    controller's objectives are the means over its trajectories, balanced
    (schemas.objectives.balancing_weights) so that each trajectory counts alike at the default
    gains: unweighted, a pyramid's f_t, 10-40 times a spiral's, would make up nearly all of it."""
    chosen = tuple(d for d in DESIGNS if d in designs)
    preregister(experiment.out, reps, chosen, kinds)
    duration = base.trajectories[0].duration
    defaults = default_points(experiment, base, ALL_KINDS)  # every kind some generic set holds
    tests = {kind.value: TrajectorySpec(kind=kind, duration=duration) for kind in kinds}

    def balanced(trained_on: tuple[TrajectorySpec, ...], rep: int) -> RunConfig:
        weights = balancing_weights([defaults[t.kind] for t in trained_on])
        return base.model_copy(
            update={"trajectories": trained_on, "objective_weights": weights, "seed": rep}
        )

    def judge(name: str, config: RunConfig, on: Sequence[str]) -> dict[str, Judged]:
        """The run `name`'s front on each test trajectory of `on` (its own, or simulated again
        there), with its recommended member picked on its own trajectories."""
        record = experiment.tune(name, config)
        pick = measures.recommended(record)
        if pick is None:
            raise ValueError(f"{record.directory}: an empty front, nothing to judge")
        index = record.front.index(pick.member)
        judged = {}
        for kind in on:
            test = tests[kind]
            points = (
                front_points(record)
                if config.trajectories == (test,)
                else experiment.evaluate(f"{name}-on-{kind}", record.front, test, base)
            )
            judged[kind] = Judged(points, pick.name, points[index])
        return judged

    def run_name(design: str, controller: str, kind: str, rep: int) -> str:
        if controller == SPECIFIC:
            return f"specific-{kind}-rep{rep}"
        return f"generic-all-rep{rep}" if design == PAPER else f"generic-no-{kind}-rep{rep}"

    plan: dict[str, tuple[RunConfig, list[str]]] = {}
    for rep in range(reps):
        for kind, test in tests.items():
            plan[run_name(PAPER, SPECIFIC, kind, rep)] = (
                base.model_copy(update={"trajectories": (test,), "seed": rep}),
                [kind],
            )
            if HELD_OUT in chosen:
                plan[run_name(HELD_OUT, GENERIC, kind, rep)] = (
                    balanced(generic_set(test.kind, duration), rep),
                    [kind],
                )
        if PAPER in chosen:
            every = tuple(TrajectorySpec(kind=kind, duration=duration) for kind in ALL_KINDS)
            plan[run_name(PAPER, GENERIC, "", rep)] = (balanced(every, rep), list(tests))
    done = experiment.concurrently(
        {name: functools.partial(judge, name, *task) for name, task in plan.items()}
    )

    def of(design: str, controller: str, kind: str) -> list[Judged]:
        return [done[run_name(design, controller, kind, rep)][kind] for rep in range(reps)]

    judged_on = {kind: [on[kind].points for on in done.values() if kind in on] for kind in tests}
    normalisations = {kind: experiment.normalisation(sets) for kind, sets in judged_on.items()}
    # One torque smoothness per test trajectory, the least every front judged there reaches.
    levels = {
        kind: measures.smoothness_level(sets, experiment.penalised)
        for kind, sets in judged_on.items()
    }
    experiment.write_normalisation({f"on {k}": n for k, n in normalisations.items()})
    rows = []
    for design in chosen:
        for kind in tests:
            level = levels[kind]
            for controller, other in ((GENERIC, SPECIFIC), (SPECIFIC, GENERIC)):
                others = of(design, other, kind)
                for rep, judged in enumerate(of(design, controller, kind)):
                    points = judged.points
                    rows.append(
                        {
                            "design": design,
                            "test_trajectory": kind,
                            "controller": controller,
                            "rep": rep,
                            "seed": rep,
                            "run": run_name(design, controller, kind, rep),
                            "hypervolume": normalisations[kind].hypervolume(points),
                            "best_f_acc": min(p[0] for p in points),
                            "f_t_level": level,
                            "error_at_level": measures.error_at(
                                points, level, experiment.penalised
                            ),
                            "recommended": judged.pick,
                            "recommended_f_acc": judged.picked[0],
                            "recommended_f_t": judged.picked[1],
                            "recommended_penalty": is_penalty(judged.picked, experiment.penalised),
                            "points": len(points),
                            "dominated_by_other": dominated_count(points, others[rep].points),
                        }
                    )
    experiment.write_results(rows)
    fronts = {
        kind: {
            label: [judged.points for judged in of(design, controller, kind)]
            for design in chosen
            for controller, label in ((SPECIFIC, SPECIFIC), (GENERIC, GENERIC_LABELS[design]))
        }
        for kind in tests
    }
    report(experiment, base, reps, chosen, rows, defaults, normalisations, fronts)


def _values(
    rows: Sequence[Mapping[str, object]], design: str, kind: str, controller: str, column: str
) -> list[float]:
    return [
        float(r[column])  # type: ignore[arg-type]
        for r in rows
        if (r["design"], r["test_trajectory"], r["controller"]) == (design, kind, controller)
    ]


def _dominated_shares(
    rows: Sequence[Mapping[str, object]], design: str, kind: str, controller: str
) -> list[float]:
    """Per repetition, the share of `controller`'s points the other's front dominates."""
    return [
        d / n if n else 0.0
        for d, n in zip(
            _values(rows, design, kind, controller, "dominated_by_other"),
            _values(rows, design, kind, controller, "points"),
            strict=True,
        )
    ]


def described(a: Sequence[float], b: Sequence[float]) -> stats.Comparison:
    """`a` against `b`, paired by repetition, pairs with an undefined side left out: an effect
    size with its bootstrap CI, not a test (the p-value NaN: no claim rests on it)."""
    kept = [(x, y) for x, y in zip(a, b, strict=True) if math.isfinite(x) and math.isfinite(y)]
    result = stats.compare([x for x, _ in kept], [y for _, y in kept], paired=True)
    return replace(result, p_value=math.nan)


def effect_text(result: stats.Comparison, unit: str, reps: int) -> str:
    """'8.73 against 11.9 mm (-3.22 mm [-4.1, -2.05])': the medians, their difference and its
    95 % bootstrap interval (measures.difference), and how many repetitions gave both."""
    if not result.n_a:
        return "undefined in every repetition"
    fewer = f", from {result.n_a} of {reps} repetitions" if result.n_a < reps else ""
    return (
        f"{result.median_a:.3g} against {result.median_b:.3g} {unit} "
        f"({measures.difference(result, unit)}{fewer})"
    )


def report(
    experiment: Experiment,
    base: RunConfig,
    reps: int,
    designs: Sequence[str],
    rows: Sequence[Mapping[str, object]],
    defaults: Mapping[TrajectoryKind, Point],
    normalisations: Mapping[str, Normalisation],
    fronts: Mapping[str, Mapping[str, list[list[Point]]]],
) -> None:
    """stats.csv, the figure and report.md from results.csv's `rows`; `fronts`: per test
    trajectory, each kind of controller's fronts judged there, a set per repetition."""
    kinds = list(fronts)
    claims: dict[tuple[str, str, str], stats.Comparison] = {}
    effects: dict[tuple[str, str, str], stats.Comparison] = {}
    for design in designs:
        for kind in kinds:
            claims[(design, kind, "hypervolume")] = stats.compare(
                _values(rows, design, kind, SPECIFIC, "hypervolume"),
                _values(rows, design, kind, GENERIC, "hypervolume"),
            )
            # The same repetition's two fronts, point against point: the share of the generic
            # points the specific front dominates, against the share of the specific ones the
            # generic front dominates (Wilcoxon signed-rank, paired by repetition).
            claims[(design, kind, "dominated_share")] = stats.compare(
                _dominated_shares(rows, design, kind, GENERIC),
                _dominated_shares(rows, design, kind, SPECIFIC),
                paired=True,
            )
            for column, effect in EFFECTS.items():
                effects[(design, kind, column)] = described(
                    *(
                        [v * effect.scale for v in _values(rows, design, kind, c, column)]
                        for c in (SPECIFIC, GENERIC)
                    )
                )
    adjusted = stats.holm_adjusted(claims)
    experiment.write_stats(
        [
            stats.StatsRow(NAME, f"{design}: specific vs generic, on {kind}", metric, result)
            for (design, kind, metric), result in claims.items()
        ]
        + [
            stats.StatsRow(
                NAME, f"{design}: specific vs generic, on {kind}", EFFECTS[column].metric, result
            )
            for (design, kind, column), result in effects.items()
        ]
    )
    sections = []
    for design in designs:
        sections += ["", f"## {QUESTIONS[design]}", ""]
        sections += design_findings(design, kinds, rows, adjusted, effects, reps)
    runs = {r["run"]: r["recommended"] for r in rows}
    closest = sum(pick == "closest" for pick in runs.values())
    diverged = len({(r["run"], r["test_trajectory"]) for r in rows if r["recommended_penalty"]})
    findings = "\n".join(
        [
            ("Two questions, one design each" if len(designs) > 1 else "One design")
            + f", {len(claims)} claims in all: the hypervolume and "
            "the dominance test of each design on each test trajectory, Holm-adjusted as one "
            f"family (every p-value below; alpha {stats.ALPHA:g}). The table's Δ: specific − "
            "generic, the difference of the medians over repetitions (below zero, the specific "
            "controller is the more accurate or the smoother).",
            *sections,
            "",
            "The effects in physical units are estimates beside the claims, not tests (no "
            "p-value; no finding rests on them, so Holm does not count them; their 95 % "
            "bootstrap CIs are not adjusted): specific against generic, the same repetition's "
            "two runs. The error at one torque smoothness is each front's best error among its "
            "members at least that smooth on the test trajectory, interpolated along the front "
            "(analytic/experiments/measures.py), at the least f_t every front judged there "
            "reaches: "
            + "; ".join(
                f"{kind} {next(r['f_t_level'] for r in rows if r['test_trajectory'] == kind):.3g}"
                " (N·m)²"
                for kind in kinds
            )
            + ". The recommended controller is what `analytic export` gives (the knee among "
            "the members that dominate the default gains on the run's own trajectories; where "
            "none does, the closest to dominating them: "
            f"{closest} of {len(runs)} runs), simulated on the test trajectory"
            + (
                f"; {diverged} of them diverged there (a penalty, not a measurement)"
                if diverged
                else ""
            )
            + ".",
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
    hypervolumes = {
        kind: {
            label: _values(rows, design, kind, controller, "hypervolume")
            for design in designs
            for controller, label in ((SPECIFIC, SPECIFIC), (GENERIC, GENERIC_LABELS[design]))
        }
        for kind in kinds
    }
    figure(experiment.out / FIGURE, hypervolumes, fronts)
    spaces = {f"on {k}": (n.ideal, n.nadir) for k, n in normalisations.items()}
    floor = min((r.min_p for r in adjusted.values()), default=1.0)
    write_experiment_report(
        experiment.out / "report.md",
        title="Generic against specific controllers: the paper's design and held out",
        setup=[
            *experiment_setup(base, reps, spaces),
            f"preregistered: {reps} repetitions, designs {', '.join(designs)}, test "
            f"trajectories {', '.join(kinds)}, fixed in `{PREREGISTRATION_JSON}` before the "
            "first run; never extended once results are seen (resuming with another --reps or "
            "--design is refused)",
            f"claims: {len(claims)} tests, one Holm family (the p-values in this report; "
            f"`stats.csv` holds the raw ones). With {reps} repetitions the smallest adjusted "
            f"p-value a claim can reach is {floor:.3g}; every claim can reach p < "
            f"{stats.ALPHA:g} from {stats.least_reps(len(claims), (True, False))} repetitions",
        ],
        table=table(
            {
                (design, kind): (
                    statistics.median(_values(rows, design, kind, SPECIFIC, "hypervolume")),
                    statistics.median(_values(rows, design, kind, GENERIC, "hypervolume")),
                    *(
                        effects[(design, kind, c)].median_a - effects[(design, kind, c)].median_b
                        for c in EFFECTS
                    ),
                )
                for design in designs
                for kind in kinds
            }
        ),
        findings=findings,
        figures=[FIGURE],
    )


def design_findings(
    design: str,
    kinds: Sequence[str],
    rows: Sequence[Mapping[str, object]],
    adjusted: Mapping[tuple[str, str, str], stats.Comparison],
    effects: Mapping[tuple[str, str, str], stats.Comparison],
    reps: int,
) -> list[str]:
    """One design's section of the findings: its headline, then a line per test trajectory."""

    def count(metric: str, winner: str) -> int:
        return sum(stats.better(adjusted[(design, k, metric)]) == winner for k in kinds)

    n = len(kinds)
    by = (
        f"by hypervolume ({LOG_NOTE}) the specific controller is significantly better on "
        f"{count('hypervolume', 'a')} of {n} test trajectories and the generic one on "
        f"{count('hypervolume', 'b')}; by the share of each other's points the fronts "
        f"dominate, on {count('dominated_share', 'a')} and {count('dominated_share', 'b')}."
    )
    if design == PAPER:
        lines = [
            "The paper found specific controllers better than generic ones. Against a generic "
            "controller tuned on every trajectory, the test one included, as the paper tuned "
            "it: " + by
        ]
    else:
        lines = [
            "A specialist beating a controller that never saw its path is expected; the "
            "question is how much the generic one loses there. Against a generic controller "
            "tuned on the other trajectories: " + by + " A difference the tests cannot decide "
            "is no evidence that the controller transfers: the effects in mm and (N·m)² say "
            "how large the loss may be."
        ]
    lines.append("")
    place = "in the generic set" if design == PAPER else "held out of the generic set"
    for kind in kinds:
        of = functools.partial(_values, rows, design, kind)
        physical = "; ".join(
            f"{effect.what} {effect_text(effects[(design, kind, column)], effect.unit, reps)}"
            for column, effect in EFFECTS.items()
        )
        lines.append(
            f"- on the {kind} ({place}): hypervolume ({LOG_NOTE}): "
            + stats.decide(
                adjusted[(design, kind, "hypervolume")],
                "the specific controller",
                "the generic one",
            )
            + f". Specific points dominate {int(sum(of(GENERIC, 'dominated_by_other')))} of "
            f"{int(sum(of(GENERIC, 'points')))} generic points; generic points dominate "
            f"{int(sum(of(SPECIFIC, 'dominated_by_other')))} of "
            f"{int(sum(of(SPECIFIC, 'points')))} specific points (each repetition against the "
            "same repetition). By dominance, paired by repetition: "
            + stats.decide(
                adjusted[(design, kind, "dominated_share")],
                "the specific controller",
                "the generic one",
            )
            + ". Specific against generic, medians over repetitions (their difference [95 % CI]): "
            + physical
            + "."
        )
    return lines


def table(effects: Mapping[tuple[str, str], Sequence[float]]) -> list[str]:
    """(design, test trajectory) → the specific and the generic controller's median
    hypervolume there, and the effects' median differences (specific − generic)."""
    return markdown_table(
        [
            "design",
            "judged on",
            "specific median hypervolume",
            "generic median hypervolume",
            *(f"Δ {effect.what} ({effect.unit})" for effect in EFFECTS.values()),
        ],
        (
            [
                design,
                kind,
                *(f"{value:.4f}" for value in values[:2]),
                *(f"{v:+.3g}" for v in values[2:]),
            ]
            for (design, kind), values in effects.items()
        ),
        text_columns=2,
    )


def figure(
    path: Path,
    hypervolumes: Mapping[str, Mapping[str, list[float]]],
    fronts: Mapping[str, Mapping[str, list[list[Point]]]],
) -> None:
    """Per test trajectory (a column each): hypervolume box plots per kind of controller on top,
    their median attainment surfaces on that trajectory below."""
    kinds = list(hypervolumes)
    canvas = new_figure((4.5 * max(1, len(kinds)), 8))
    panels = canvas.subplots(2, max(1, len(kinds)), squeeze=False)
    for column, kind in enumerate(kinds):
        top, bottom = panels[0][column], panels[1][column]
        top.boxplot(list(hypervolumes[kind].values()), tick_labels=list(hypervolumes[kind]))
        top.set(ylabel=f"hypervolume on the {kind} (log f_t)", title=f"judged on the {kind}")
        attainment_panel(bottom, fronts.get(kind, {}), f"fronts on the {kind}")
    save_png(canvas, path)


EXPERIMENT = ExperimentSpec(
    name=NAME,
    summary="the paper's generic against specific controllers: its design, and held out",
    run=run,
    help="Specific controllers (tuned on one trajectory) against generic ones, judged on each of "
    "spiral, random and pyramid in turn, in two designs, each its own question: paper (the "
    "generic controller tuned on every trajectory, the test one included) and held-out (tuned "
    "on the other two: does it transfer to a path it never saw?). --reps is preregistered: "
    "fixed in the experiment directory before the first run, and never changed there.",
    options=(
        Option(
            "--design",
            "designs",
            "paper (generic tuned on every trajectory), held-out (on the others), or both; "
            "fixed, with --reps, before the first run",
            "both",
            chosen_designs,
            "paper|held-out|both",
        ),
    ),
    trajectories=lambda base, _options: [
        TrajectorySpec(kind=kind, duration=base.trajectories[0].duration) for kind in ALL_KINDS
    ],
)
