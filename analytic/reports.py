"""Reports in plain words: a run's report.md, and an experiment's with its verdict.

Like the figures, edge code on plain data: the caller computes, these functions only say it.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from analytic.config import RunConfig
from analytic.records import (
    FRONT_CSV,
    HISTORY_CSV,
    HYPERVOLUME_PNG,
    PARETO_PNG,
    FrontMember,
    HistoryRow,
    sorted_front,
)
from schemas.files import write_atomically
from schemas.robot import PLANTS, ModelSpec

ALGORITHM_NAMES = {
    "nsga2": "NSGA-II",
    "nsga3": "NSGA-III",
    "smsemoa": "SMS-EMOA",
    "moead": "MOEA/D",
    "agemoea2": "AGE-MOEA-II",
    "tpe": "Optuna TPE",
    "random": "uniform random search",
}


def _search(config: RunConfig) -> str:
    """How the run searched: 'generational NSGA-II', 'steady-state NSGA-II', ..."""
    how = "steady-state" if config.asynchronous else "generational"
    name = ALGORITHM_NAMES.get(config.algorithm, config.algorithm)
    scaled = ", told log f_t" if config.objective_scaling == "log" else ""
    return f"{how} {name}{scaled}"


def run_title(config: RunConfig) -> str:
    """A run's figures' title: what was tuned, how."""
    return f"{config.mode} controller, {_search(config)}, pop {config.pop}, seed {config.seed}"


def run_setup(config: RunConfig) -> list[str]:
    """A run's configuration as its report lists it."""
    trajectories = ", ".join(
        f"{trajectory.kind.value} {trajectory.duration:g} s" for trajectory in config.trajectories
    )
    controller = config.mode + " controller"
    if config.feedforward is not None:
        controller = f"{config.mode} PD + learned feed-forward {config.feedforward[:12]}"
    weights = config.objective_weights
    averaged = (
        ""
        if weights is None
        else "; objectives averaged with weights f_acc "
        + " / ".join(f"{w:.2f}" for w, _ in weights)
        + ", f_t "
        + " / ".join(f"{w:.2f}" for _, w in weights)
    )
    return [
        f"{controller} on {trajectories}{averaged}",
        f"{_search(config)}, population {config.pop}, seed {config.seed}",
        f"{plant_text(config.model)}; reference point "
        f"f_acc {config.reference_point[0]} m, f_t {config.reference_point[1]}",
    ]


def _duration(seconds: float) -> str:
    """Wall time the way a person says it: 42.0 s, 3 min 07 s, 2 h 05 min."""
    if not math.isfinite(seconds):
        return str(seconds)
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, second = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {second:02d} s"
    hours, minute = divmod(minutes, 60)
    return f"{hours} h {minute:02d} min"


def gains_text(member: FrontMember) -> str:
    """A member's 14 gains on one short line: 'kp 2000 2000 1200 … / kd 20 20 15 …'."""
    kp = " ".join(f"{gain:.4g}" for gain in member.kp)
    kd = " ".join(f"{gain:.4g}" for gain in member.kd)
    return f"kp {kp} / kd {kd}"


def front_table_row(rank: int, member: FrontMember) -> str:
    """One line of the report's front table (public so a test or a caller can find it)."""
    return f"| {rank} | {member.f_acc * 1000:.3f} | {member.f_t:.4g} | {gains_text(member)} |"


def report_markdown(
    *,
    title: str,
    config_lines: Sequence[str],
    history: Sequence[HistoryRow],
    front: Sequence[FrontMember],
    converged: str,
) -> str:
    """The text of report.md (see `write_report`)."""
    lines = [f"# {title}", "", "## Configuration", ""]
    lines += [f"- {line}" for line in config_lines] or ["- (none given)"]
    lines += ["", "## Summary", ""]
    if history:
        last = history[-1]
        lines += [
            f"- generations: {len(history)}",
            f"- evaluations: {last.evaluations}",
            f"- final hypervolume: {last.hypervolume:.6g}",
            f"- best f_acc: {last.best_f_acc * 1000:.3f} mm; best f_t: {last.best_f_t:.4g} (N·m)²",
            f"- wall time: {_duration(last.wall_seconds)}",
        ]
    else:
        lines.append("- no generation finished yet")
    if converged:
        lines.append(f"- {converged}")

    members = sorted_front(front)
    lines += ["", f"## Pareto front ({len(members)} members, most accurate first)", ""]
    if members:
        lines += [
            "| # | f_acc (mm) | f_t ((N·m)²) | gains |",
            "|---:|---:|---:|---|",
            *(front_table_row(rank, member) for rank, member in enumerate(members, start=1)),
        ]
    else:
        lines.append("No members yet.")

    lines += [
        "",
        "## Figures",
        "",
        f"![Pareto front]({PARETO_PNG})",
        "",
        f"![Hypervolume against evaluations]({HYPERVOLUME_PNG})",
        "",
        f"The numbers at full precision: [{FRONT_CSV}]({FRONT_CSV}) (the front, gains and scores) "
        f"and [{HISTORY_CSV}]({HISTORY_CSV}) (one row per generation).",
        "",
    ]
    return "\n".join(lines)


def write_report(
    path: Path,
    *,
    title: str,
    config_lines: Sequence[str],
    history: Sequence[HistoryRow],
    front: Sequence[FrontMember],
    converged: str,
) -> None:
    """A short report.md at `path`: configuration, summary, the front as a table, the figures.

    `converged` is the caller's one-line verdict on why the run stopped (or that it has not),
    e.g. "converged after 240 evaluations (hypervolume gain < 0.1% over 3 generations)". The
    figures and CSVs are linked by their standard names relative to the report, so write them
    into the same directory. The table is rounded for reading; front.csv holds the exact values.
    """
    text = report_markdown(
        title=title, config_lines=config_lines, history=history, front=front, converged=converged
    )
    write_atomically(Path(path), text.encode("utf-8"))


def plant_text(model: ModelSpec) -> str:
    """Which plant a run simulated: a named one, or a custom one, and its joints."""
    for name, plant in PLANTS.items():
        if model == plant.model_copy(update={"joints": model.joints}):
            return f"{name} plant, {model.joints} joints"
    return f"custom plant (see config.json), {model.joints} joints"


def experiment_setup(
    base: RunConfig, reps: int, normalisations: dict[str, tuple[tuple[float, float], ...]]
) -> list[str]:
    """How an experiment was run, as its report lists it; `normalisations`: per problem (the
    trajectory fronts are judged on), the ideal and nadir points the hypervolume spans."""
    spaces = "; ".join(
        f"{problem}: f_acc {ideal[0]:.4g}-{nadir[0]:.4g} m, "
        f"f_t {ideal[1]:.4g}-{nadir[1]:.4g} (N·m)²"
        for problem, (ideal, nadir) in normalisations.items()
    )
    return [
        f"{reps} repetitions (seeds 0..{reps - 1}); base configuration: population "
        f"{base.pop}, {base.termination_text}, {plant_text(base.model)}",
        "hypervolume normalised between the ideal and the nadir of the pooled non-dominated "
        f"front of each problem (penalty points left out; f_t on a log scale): {spaces} "
        "(`normalisation.json`)",
        "comparisons: Mann-Whitney U (Wilcoxon signed-rank when paired), Vargha-Delaney A12 = "
        "P(a > b) + 0.5 P(a = b), bootstrap 95 % CI of the difference of medians "
        "(`stats.csv`); alpha 0.05",
        "runs in `runs/`, raw numbers in `results.csv`",
    ]


def popsize_table(medians: dict[int, tuple[float, float]]) -> list[str]:
    """Population size → (median hypervolume, median evaluations), as a Markdown table."""
    table = ["| population | median hypervolume | median evaluations |", "|---:|---:|---:|"]
    return table + [
        f"| {s} | {hv:.4f} | {evaluations:.0f} |" for s, (hv, evaluations) in medians.items()
    ]


def controllers_table(medians: dict[tuple[str, str], float]) -> list[str]:
    """(test trajectory, kind of controller) → median hypervolume on that trajectory."""
    kinds = list(dict.fromkeys(kind for kind, _ in medians))
    controllers = list(dict.fromkeys(controller for _, controller in medians))
    table = [
        "| judged on | " + " | ".join(f"{c} median hypervolume" for c in controllers) + " |",
        "|---|" + "---:|" * len(controllers),
    ]
    return table + [
        f"| {kind} | " + " | ".join(f"{medians[(kind, c)]:.4f}" for c in controllers) + " |"
        for kind in kinds
    ]


def speed_table(durations: Sequence[float], error: dict[tuple[float, float], float]) -> list[str]:
    """The most accurate controller's error, tuned-on duration against evaluated-on duration."""
    table = [
        "| tuned on | " + " | ".join(f"on {d:g} s" for d in durations) + " |",
        "|---|" + "---:|" * len(durations),
    ]
    return table + [
        f"| {t:g} s | " + " | ".join(f"{error[(t, u)] * 1000:.2f} mm" for u in durations) + " |"
        for t in durations
    ]


@dataclass(frozen=True)
class ConditionSummary:
    """A condition of the algorithms study over its repetitions, as its table shows it."""

    algorithm: str
    scaling: str
    runs: int
    median_hypervolume: float
    hypervolume_quartiles: tuple[float, float]
    median_best_f_acc: float  # m
    median_evaluations_to_target: float  # inf when fewer than half of the runs reach it
    reached_target: int  # runs that reach it


def condition_text(algorithm: str, scaling: str) -> str:
    """An optimiser and what it is told, as a reader says it: 'NSGA-II, log f_t'."""
    told = "log f_t" if scaling == "log" else scaling
    return f"{ALGORITHM_NAMES.get(algorithm, algorithm)}, {told}"


def algorithms_table(
    summaries: Sequence[ConditionSummary], baselines: dict[str, tuple[float, float]]
) -> list[str]:
    """One row per condition, then one per no-GA baseline (`baselines`: its name → its
    hypervolume and best f_acc in m, one deterministic set each, so no spread)."""
    table = [
        "| condition | runs | median hypervolume | interquartile range | median best error (mm) "
        "| median evaluations to 99 % |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for s in summaries:
        low, high = s.hypervolume_quartiles
        reached = (
            "not reached"
            if math.isinf(s.median_evaluations_to_target)
            else f"{s.median_evaluations_to_target:.0f}"
        )
        table.append(
            f"| {condition_text(s.algorithm, s.scaling)} | {s.runs} | "
            f"{s.median_hypervolume:.4f} | {low:.4f}-{high:.4f} | "
            f"{s.median_best_f_acc * 1000:.3f} | {reached} ({s.reached_target} of {s.runs} "
            "runs reach it) |"
        )
    table += [
        f"| {name}, no GA | – | {hypervolume:.4f} | – | {best_f_acc * 1000:.3f} | – |"
        for name, (hypervolume, best_f_acc) in baselines.items()
    ]
    return table


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


def dataset_value_table(
    means: dict[tuple[str, str], tuple[float, float]], reference: float | None = None
) -> list[str]:
    """(model, condition) → (mean, sd) of the test nMSE: conditions as rows, models as
    columns, "mean ± sd"; the rigid prior's single score as a last row, if given."""
    models = list(dict.fromkeys(model for model, _ in means))
    conditions = list(dict.fromkeys(condition for _, condition in means))

    def cell(mean: float, sd: float) -> str:
        return f"{mean:.4f}" if not math.isfinite(sd) else f"{mean:.4f} ± {sd:.4f}"

    table = [
        "| condition | " + " | ".join(f"{model} nMSE" for model in models) + " |",
        "|---|" + "---:|" * len(models),
    ]
    table += [
        f"| {condition} | "
        + " | ".join(cell(*means[(model, condition)]) for model in models)
        + " |"
        for condition in conditions
    ]
    if reference is not None:
        table.append(
            "| (rigid prior, untrained) | " + " | ".join(f"{reference:.4f}" for _ in models) + " |"
        )
    return table


class PairedComparison(Protocol):
    """What a comparisons table shows of one paired comparison (analytic.dataset_value's)."""

    model: str
    condition: str
    against: str
    mean_difference: float
    t: float
    p: float
    p_holm: float
    d_z: float
    n: int


def comparisons_table(comparisons: Sequence[PairedComparison]) -> list[str]:
    """Paired comparisons as a Markdown table; a difference below zero means lower nMSE. An
    untested value (too few repetitions) shows as a dash."""

    def number(value: float, fmt: str) -> str:
        return "–" if math.isnan(value) else format(value, fmt)

    table = [
        "| model | condition | against | mean difference | t | p | p (Holm) | d_z | n |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for c in comparisons:
        table.append(
            f"| {c.model} | {c.condition} | {c.against} | {number(c.mean_difference, '+.4f')} | "
            f"{number(c.t, '.2f')} | {number(c.p, '.3g')} | {number(c.p_holm, '.3g')} | "
            f"{number(c.d_z, '+.2f')} | {c.n} |"
        )
    return table


def write_dataset_value_report(
    path: Path,
    *,
    setup: Sequence[str],
    means: dict[tuple[str, str], tuple[float, float]],
    reference: float | None,
    comparisons: Sequence[PairedComparison],
    verdict: str,
    limitations: Sequence[str],
    figure: str,
) -> None:
    """The dataset-value experiment's report.md: setup, nMSE table, comparisons, verdict,
    limitations, figure."""
    lines = [
        "# The value of tuned controllers' data for learning the dynamics",
        "",
        *[f"- {line}" for line in setup],
        "",
        "## Test nMSE (mean ± sd over repetitions)",
        "",
        *dataset_value_table(means, reference),
        "",
        "## Verdict",
        "",
        verdict,
        "",
        "## Paired comparisons",
        "",
        "Difference = the condition's nMSE minus the other's, paired by repetition (below zero: "
        "its data taught more); paired t-test, Cohen's d_z = mean difference / sd of the "
        "differences; Holm's adjustment across the ten comparisons of each model (the last row, "
        "best selection against runner-up, is one test of its own).",
        "",
        *comparisons_table(comparisons),
        "",
        "## Limitations",
        "",
        *[f"- {line}" for line in limitations],
        "",
        f"![{figure}]({figure})",
        "",
    ]
    write_atomically(Path(path), "\n".join(lines).encode())
