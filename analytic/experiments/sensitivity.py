"""What the plant's assumptions do to the findings: each uncertain parameter of the plant moved
over its stated range, the tuning repeated on each moved plant (`reps` runs each, seed = rep),
and the results set against the nominal plant's.

The parameters (models/uncertainty.toml gives each range's source, or says it is an
assumption): the reflected rotor inertia B ×5, the Coulomb friction ×0.5 and ×2, every link's
mass ±10 % (the robot's gravity model does not know it), the joint stiffness ×0.5 and ×2, the
command delay 2 and 3 ticks (1 nominal). A setting moves the nominal plant and every plant
variant of robust tuning alike; the physics steps grow where stiffer springs need them.

What is compared, each moved setting against the nominal plant (Mann-Whitney U, Holm-adjusted
over every comparison of the experiment: one family): the front's hypervolume (one normalised
space over every run, "all plants"), the recommended controller's error and f_t
(analytic.tuning.picks: the closest to dominating the default gains where none does), and
whether the nominal plant's recommended controller still holds on the moved one: it is run
there beside the default gains, and its error set against the re-tuned recommended
controller's.

Written: results.csv (a row per run), stats.csv (unadjusted p-values; report.md gives the
adjusted ones), normalisation.json, sensitivity.png and report.md, which ends with the table of
which conclusions survive the plant's assumptions.
"""

import functools
import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.normalisation import Point, front_points
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option
from gainfarm.analytic.experiments.report import (
    attainment_panel,
    experiment_setup,
    markdown_table,
    write_experiment_report,
)
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.picks import dominates, picks
from gainfarm.analytic.tuning.plants import ranges
from gainfarm.analytic.tuning.records import BASELINE_JSON, RunRecord, read_baseline
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.models import min_substeps, resolve
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec
from gainfarm.schemas.wire import describe

NAME = "sensitivity"
FIGURE = "sensitivity.png"
SPACE = "all plants"  # the one problem: normalisation.json's key
NOMINAL = "nominal"


@dataclass(frozen=True)
class Parameter:
    """One uncertain group of the plant's numbers and the settings it is moved to: factors on
    the nominal values, or (`absolute`) the value itself."""

    name: str  # as --parameters names it
    what: str  # as the report names it
    field: str  # PlantSpec's field, dotted into a sub-model
    settings: tuple[float, ...]
    uncertainty: str  # its entry in models/uncertainty.toml
    absolute: bool = False

    def label(self, value: float) -> str:
        return f"{value:g} ticks" if self.absolute else f"×{value:g}"

    def slug(self, value: float) -> str:
        return f"{self.name}-{value:g}" if self.absolute else f"{self.name}-x{value:g}"


PARAMETERS = {
    p.name: p
    for p in (
        Parameter("rotor", "rotor inertia B", "rotor_inertia", (5.0,), "rotor_inertia"),
        Parameter("coulomb", "Coulomb friction", "friction.coulomb", (0.5, 2.0), "coulomb"),
        Parameter("mass", "link masses", "mass_scale", (0.9, 1.1), "mass_scale"),
        Parameter("stiffness", "joint stiffness", "stiffness", (0.5, 2.0), "stiffness"),
        Parameter("delay", "command delay", "delay", (2.0, 3.0), "delay", absolute=True),
    )
}


@dataclass(frozen=True)
class Setting:
    """One moved plant: a parameter at one of its settings."""

    parameter: Parameter
    value: float

    @property
    def label(self) -> str:
        return f"{self.parameter.name} {self.parameter.label(self.value)}"

    @property
    def key(self) -> str:
        """Its name in the runs' names and results.csv's plant column."""
        return self.parameter.slug(self.value)


def settings_of(names: Sequence[str]) -> list[Setting]:
    return [Setting(PARAMETERS[n], value) for n in names for value in PARAMETERS[n].settings]


def moved(plant: PlantSpec, setting: Setting) -> PlantSpec:
    """`plant` with `setting`'s parameter moved, and the physics steps its springs need;
    ValueError (one line) if the plant has no such number or the result is no plant."""
    parameter = setting.parameter
    values = resolve(plant).model_dump()  # the robot's own numbers, written out to move
    *parents, name = parameter.field.split(".")
    holder = values
    for parent in parents:
        holder = holder.get(parent)
        if holder is None:
            raise ValueError(f"the plant has no {parent} to move")
    current = holder[name]
    if parameter.absolute:
        holder[name] = type(current)(setting.value)
    else:
        holder[name] = tuple(v * setting.value for v in current)
    try:
        result = PlantSpec.model_validate(values)
    except ValidationError as error:
        raise ValueError(describe(error)) from None
    needed = min_substeps(result)
    return result.model_copy(update={"substeps": max(result.substeps, needed)})


def moved_config(base: RunConfig, setting: Setting) -> RunConfig:
    """`base` on the moved plant: the nominal plant, and robust tuning's variants alike."""
    return base.model_copy(
        update={
            "plant": moved(base.plant, setting),
            "plants": tuple(moved(p, setting) for p in base.plants),
            "check_plants": tuple(moved(p, setting) for p in base.check_plants),
        }
    )


# --- one run's outcome --------------------------------------------------------------------------


@dataclass(frozen=True)
class RunOutcome:
    """What one run says: its front, its hypervolume and the controller it recommends
    (`pick`: recommended, or closest when no member dominates the default gains)."""

    front: list[Point]
    hypervolume: float
    pick: str
    gains: PDGains
    error_m: float
    f_t: float


def outcome(record: RunRecord, hypervolume: Callable[[Sequence[Point]], float]) -> RunOutcome:
    baseline = read_baseline(record.directory / BASELINE_JSON)
    chosen = picks(record.front, baseline)[0]
    return RunOutcome(
        front=front_points(record),
        hypervolume=hypervolume(front_points(record)),
        pick=chosen.name,
        gains=chosen.member.gains,
        error_m=chosen.member.f_acc,
        f_t=chosen.member.f_t,
    )


@dataclass(frozen=True)
class Transfer:
    """The nominal plant's recommended controller and the default gains, run on a moved plant."""

    nominal: Point
    defaults: Point

    @property
    def holds(self) -> bool:
        """Whether the nominal's controller still dominates the default gains there."""
        return dominates(self.nominal, self.defaults)


# --- the experiment -----------------------------------------------------------------------------


# stats.csv's metrics: what the report calls each, and whether higher is better. RETUNED is on
# the moved plant: its re-tuned recommended controller against the nominal's.
METRICS = {
    "hypervolume": ("hypervolume", True),
    "recommended_error_mm": ("recommended error", False),
    "recommended_f_t": ("recommended f_t", False),
}
RETUNED = "retuned_vs_nominal_controller_error_mm"


def run(
    experiment: Experiment,
    base: RunConfig,
    reps: int,
    parameters: Sequence[str] = tuple(PARAMETERS),
) -> None:
    """Tune on the nominal plant and on each moved one; compare each with the nominal."""
    settings = settings_of(parameters)
    configs = {NOMINAL: base, **{s.key: moved_config(base, s) for s in settings}}
    plan = {
        (key, rep): (f"{key}-rep{rep}", config.model_copy(update={"seed": rep}))
        for key, config in configs.items()
        for rep in range(reps)
    }
    tuned = experiment.tune_many(dict(plan.values()))
    records = {key: tuned[name] for key, (name, _) in plan.items()}
    normalisation = experiment.normalisation([front_points(r) for r in records.values()])
    experiment.write_normalisation({SPACE: normalisation})
    outcomes = {key: outcome(r, normalisation.hypervolume) for key, r in records.items()}
    trajectory = base.trajectories[0]
    transfers: dict[tuple[str, int], Transfer] = {
        key: Transfer(*points)
        for key, points in experiment.concurrently(
            {
                (key, rep): functools.partial(
                    experiment.evaluate_gains,
                    f"{key}-rep{rep}-nominal-controller",
                    [outcomes[(NOMINAL, rep)].gains, base.default_gains],
                    trajectory,
                    configs[key],
                )
                for key in configs
                if key != NOMINAL
                for rep in range(reps)
            }
        ).items()
    }
    experiment.write_results(results_rows(configs, outcomes, transfers, reps))
    compared = comparisons(settings, outcomes, transfers, reps)
    adjusted = stats.holm_adjusted(compared)
    experiment.write_stats(
        [
            stats.StatsRow(NAME, f"{s.label} vs nominal", metric, result)
            for (s, metric), result in compared.items()
        ]
    )
    figure(experiment.out / FIGURE, settings, outcomes, reps)
    found = [finding(s, outcomes, transfers, adjusted, reps) for s in settings]
    write_experiment_report(
        experiment.out / "report.md",
        title="Sensitivity to the plant's assumptions",
        setup=[
            *experiment_setup(
                base,
                reps,
                {SPACE: (normalisation.ideal, normalisation.nadir)},
            ),
            "plants: the nominal one and, one parameter at a time, "
            + "; ".join(stated_ranges(parameters, base.robot)),
            f"each moved plant against the nominal: Mann-Whitney U; Holm's adjustment over all "
            f"{len(compared)} comparisons (one family; stats.csv holds the unadjusted p-values)",
        ],
        table=[*table(configs, outcomes, transfers, reps), "", f"![{FIGURE}]({FIGURE})"],
        findings=findings(found, adjusted, reps),
        figures=[],
    )


def stated_ranges(names: Sequence[str], robot: str = DEFAULT_ROBOT) -> list[str]:
    """Each parameter's settings beside the range the robot's uncertainty ranges state for it
    (the iiwa 14's: models/uncertainty.toml)."""
    table = ranges(robot=robot)
    lines = []
    for name in names:
        p = PARAMETERS[name]
        entry = table.get(p.uncertainty)
        stated = (
            f"uncertainty.toml {entry.low:g}-{entry.high:g}"
            + (" ticks" if entry.absolute else "×")
            + f", {entry.why.split(':')[0]}"  # "assumption", "source and assumption"
            if entry
            else "no range stated"
        )
        shown = ", ".join(p.label(v) for v in p.settings)
        lines.append(f"{p.what} ({p.name}) {shown} ({stated})")
    return lines


def results_rows(
    configs: Mapping[str, RunConfig],
    outcomes: Mapping[tuple[str, int], RunOutcome],
    transfers: Mapping[tuple[str, int], Transfer],
    reps: int,
) -> list[dict[str, object]]:
    rows = []
    for key in configs:
        for rep in range(reps):
            o = outcomes[(key, rep)]
            t = transfers.get((key, rep))
            rows.append(
                {
                    "plant": key,
                    "rep": rep,
                    "seed": rep,
                    "hypervolume": o.hypervolume,
                    "pick": o.pick,
                    "error_mm": o.error_m * 1000,
                    "f_t": o.f_t,
                    "nominal_controller_error_mm": t.nominal[0] * 1000 if t else "",
                    "nominal_controller_f_t": t.nominal[1] if t else "",
                    "default_gains_error_mm": t.defaults[0] * 1000 if t else "",
                    "default_gains_f_t": t.defaults[1] if t else "",
                    "nominal_controller_beats_defaults": t.holds if t else "",
                }
            )
    return rows


def samples(
    key: str, outcomes: Mapping[tuple[str, int], RunOutcome], reps: int
) -> dict[str, list[float]]:
    """A plant's runs' hypervolumes, recommended errors (mm) and f_t."""
    runs = [outcomes[(key, rep)] for rep in range(reps)]
    return {
        "hypervolume": [o.hypervolume for o in runs],
        "recommended_error_mm": [o.error_m * 1000 for o in runs],
        "recommended_f_t": [o.f_t for o in runs],
    }


def comparisons(
    settings: Sequence[Setting],
    outcomes: Mapping[tuple[str, int], RunOutcome],
    transfers: Mapping[tuple[str, int], Transfer],
    reps: int,
) -> dict[tuple[Setting, str], stats.Comparison]:
    """Each moved plant against the nominal on every metric (a: moved, b: nominal); and on the
    moved plant, its re-tuned recommended controller against the nominal's."""
    nominal = samples(NOMINAL, outcomes, reps)
    found = {}
    for s in settings:
        key = s.key
        here = samples(key, outcomes, reps)
        for metric in METRICS:
            found[(s, metric)] = stats.compare(here[metric], nominal[metric])
        found[(s, RETUNED)] = stats.compare(
            here["recommended_error_mm"],
            [transfers[(key, rep)].nominal[0] * 1000 for rep in range(reps)],
        )
    return found


@dataclass(frozen=True)
class Finding:
    """What one moved plant does to the findings: the shifts of the medians, the tests' decision
    (`decision`: survives, shifts or cannot decide), and the nominal controller there."""

    setting: Setting
    error_mm: float  # Δ median recommended error, moved − nominal
    f_t_ratio: float  # median recommended f_t, moved / nominal
    hypervolume: float  # Δ median hypervolume
    holds: int  # reps where the nominal's controller dominates the default gains here
    decision: str


def finding(
    setting: Setting,
    outcomes: Mapping[tuple[str, int], RunOutcome],
    transfers: Mapping[tuple[str, int], Transfer],
    adjusted: Mapping[tuple[Setting, str], stats.Comparison],
    reps: int,
) -> Finding:
    key = setting.key
    here, nominal = samples(key, outcomes, reps), samples(NOMINAL, outcomes, reps)
    hv = adjusted[(setting, "hypervolume")]
    error = adjusted[(setting, "recommended_error_mm")]
    shifts = []
    if stats.significant(error):
        shifts.append(f"error {'lower' if stats.better(error, False) == 'a' else 'higher'}")
    if stats.significant(hv):
        shifts.append(f"hypervolume {'higher' if stats.better(hv) == 'a' else 'lower'}")
    if shifts:
        said = "shifts: " + ", ".join(shifts)
    elif not (stats.decidable(hv) or stats.decidable(error)):
        said = f"cannot decide ({repetitions(reps)} too few after Holm)"
    else:
        said = "survives: no significant shift"
    ft_nominal = statistics.median(nominal["recommended_f_t"])
    return Finding(
        setting=setting,
        error_mm=statistics.median(here["recommended_error_mm"])
        - statistics.median(nominal["recommended_error_mm"]),
        f_t_ratio=statistics.median(here["recommended_f_t"]) / ft_nominal
        if ft_nominal > 0
        else math.nan,
        hypervolume=statistics.median(here["hypervolume"])
        - statistics.median(nominal["hypervolume"]),
        holds=sum(transfers[(key, rep)].holds for rep in range(reps)),
        decision=said,
    )


def table(
    configs: Mapping[str, RunConfig],
    outcomes: Mapping[tuple[str, int], RunOutcome],
    transfers: Mapping[tuple[str, int], Transfer],
    reps: int,
) -> list[str]:
    """Per plant, the medians: hypervolume, recommended error and f_t, how many runs found a
    member dominating the default gains, and the nominal's controller run there."""

    def nominal_there(key: str) -> str:
        if key == NOMINAL:
            return "-"
        errors = [transfers[(key, rep)].nominal[0] * 1000 for rep in range(reps)]
        return f"{statistics.median(errors):.3g} mm"

    rows = []
    for key in configs:
        s = samples(key, outcomes, reps)
        recommended = sum(outcomes[(key, rep)].pick == "recommended" for rep in range(reps))
        rows.append(
            [
                key,
                f"{statistics.median(s['hypervolume']):.4f}",
                f"{statistics.median(s['recommended_error_mm']):.3g}",
                f"{statistics.median(s['recommended_f_t']):.3g}",
                f"{recommended}/{reps}",
                nominal_there(key),
            ]
        )
    return markdown_table(
        [
            "plant",
            "median hypervolume",
            "recommended error (mm)",
            "recommended f_t ((N·m)²)",
            "runs with a recommendation",
            "nominal's controller here, error",
        ],
        rows,
    )


def findings(
    found: Sequence[Finding],
    adjusted: Mapping[tuple[Setting, str], stats.Comparison],
    reps: int,
) -> str:
    """Each comparison's decision, then the table of which conclusions survive."""
    if not found:
        return "No parameter moved: nothing to compare."
    lines = [
        f"Each moved plant against the nominal (two-sided, alpha {stats.ALPHA:g}; p-values "
        f"Holm-adjusted over all {len(adjusted)} comparisons):",
    ]
    for (s, metric), result in adjusted.items():
        if not stats.decidable(result):
            continue
        if metric == RETUNED:
            lines.append(
                f"- {s.label}, error there: "
                + stats.decide(result, "re-tuned", "the nominal's controller", False)
            )
        else:
            what, higher = METRICS[metric]
            lines.append(f"- {s.label}, {what}: " + stats.decide(result, s.label, NOMINAL, higher))
    undecidable = [r for r in adjusted.values() if not stats.decidable(r)]
    if undecidable:
        lines.append(
            f"- {len(undecidable)} of {len(adjusted)} comparisons cannot be decided: with "
            f"{reps} against {reps} repetitions and {len(adjusted)} comparisons no Holm-adjusted "
            f"p-value can fall below {stats.ALPHA:g}, whatever the data; "
            f"{stats.least_reps(len(adjusted))} repetitions per plant could decide."
        )
    groups = {
        "the recommended controller's error or the front's hypervolume shifts significantly "
        "under": [f.setting.label for f in found if f.decision.startswith("shifts")],
        "neither shifts significantly under": [
            f.setting.label for f in found if f.decision.startswith("survives")
        ],
        f"{repetitions(reps)} cannot decide under": [
            f.setting.label for f in found if f.decision.startswith("cannot")
        ],
    }
    summary = (
        f"Of {len(found)} moved plants: "
        + "; ".join(f"{said} {', '.join(labels)}" for said, labels in groups.items() if labels)
        + ". The controller the nominal plant recommends still dominates the default gains on "
        f"the moved plant in {sum(f.holds for f in found)} of {len(found) * reps} cases. "
        "'Survives' means no significant shift at these repetitions, not that none exists: the "
        "95 % confidence intervals in stats.csv (unadjusted) bound how large a shift the data "
        "leave open."
    )
    survival = markdown_table(
        [
            "parameter",
            "setting",
            "Δ recommended error (mm)",
            "recommended f_t (× nominal)",
            "Δ hypervolume",
            "nominal's controller beats the defaults here",
            "decision",
        ],
        (
            [
                f.setting.parameter.what,
                f.setting.parameter.label(f.setting.value),
                f"{f.error_mm:+.3g}",
                f"{f.f_t_ratio:.3g}",
                f"{f.hypervolume:+.4f}",
                f"{f.holds}/{reps}",
                f.decision,
            ]
            for f in found
        ),
        text_columns=2,
    )
    return "\n".join(
        [
            *lines,
            "",
            "## Which conclusions survive the plant's assumptions",
            "",
            summary,
            "",
            *survival,
        ]
    )


def repetitions(count: int) -> str:
    return f"{count} repetition{'' if count == 1 else 's'}"


def figure(
    path: Path,
    settings: Sequence[Setting],
    outcomes: Mapping[tuple[str, int], RunOutcome],
    reps: int,
) -> None:
    """Per parameter, the median attainment surfaces of the nominal plant and each setting; and
    the recommended controller's error on every plant."""
    parameters = list(dict.fromkeys(s.parameter for s in settings))
    canvas = new_figure((4.5 * (len(parameters) + 1), 4))
    panels = canvas.subplots(1, len(parameters) + 1, squeeze=False)[0]

    def fronts(key: str) -> list[list[Point]]:
        return [outcomes[(key, rep)].front for rep in range(reps)]

    for axes, parameter in zip(panels, parameters, strict=False):
        attainment_panel(
            axes,
            {
                NOMINAL: fronts(NOMINAL),
                **{s.label: fronts(s.key) for s in settings if s.parameter == parameter},
            },
            parameter.what,
        )
    keys = [NOMINAL, *(s.key for s in settings)]
    last = panels[-1]
    last.boxplot(
        [samples(key, outcomes, reps)["recommended_error_mm"] for key in keys],
        tick_labels=[NOMINAL, *(s.label for s in settings)],
    )
    last.set(ylabel="recommended controller's error (mm)", title="recommended error per plant")
    last.tick_params(axis="x", labelrotation=60)
    save_png(canvas, path)


# --- the command line ---------------------------------------------------------------------------


def parameter_names(text: str) -> list[str]:
    """--parameters: comma-separated names of PARAMETERS, each once."""
    names = [part.strip() for part in text.split(",")]
    for index, name in enumerate(names):
        if name not in PARAMETERS:
            raise ValueError(f"{name!r} is not one of {', '.join(PARAMETERS)}")
        if name in names[:index]:
            raise ValueError(f"{name!r} is named twice")
    return names


def prepare(base: RunConfig, options: Mapping[str, Any]) -> RunConfig:
    """The base configuration, once every moved plant is known to be one."""
    for s in settings_of(options.get("parameters", tuple(PARAMETERS))):
        try:
            moved_config(base, s)
        except ValueError as error:
            problem = str(error).splitlines()[0]
            raise ValueError(f"--parameters: {s.parameter.name}: {problem}") from None
    return base


EXPERIMENT = ExperimentSpec(
    name=NAME,
    summary="the plant's uncertain parameters moved one at a time, the tuning repeated on each",
    help="Each uncertain parameter of the plant moved over its stated range (rotor: the "
    "reflected rotor inertia B ×5; coulomb: Coulomb friction ×0.5, ×2; mass: every link's mass "
    "×0.9, ×1.1; stiffness: joint stiffness ×0.5, ×2; delay: 2 and 3 ticks), the tuning "
    "repeated on each moved plant (--reps runs each), and the front's hypervolume, the "
    "recommended controller and the nominal plant's controller compared with the nominal "
    "plant's, Holm-adjusted. The report ends with which conclusions survive.",
    run=run,
    options=(
        Option(
            "--parameters",
            "parameters",
            f"the parameters moved, comma-separated: {', '.join(PARAMETERS)}",
            ",".join(PARAMETERS),
            parameter_names,
            "NAME,NAME,...",
        ),
    ),
    prepare=prepare,
)
