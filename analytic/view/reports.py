"""Reports in plain words: a run's report.md (each experiment words its own:
analytic.experiments).

Like the figures, edge code on plain data: the caller computes, these functions only say it.
"""

import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import (
    FRONT_CSV,
    HISTORY_CSV,
    HYPERVOLUME_PNG,
    PARETO_PNG,
    PROVENANCE_CSV,
    Baseline,
    FrontMember,
    HistoryRow,
    ValidationRecord,
    sorted_front,
)
from gainfarm.analytic.view.export import Pick, plant_name, point_groups
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.controller import UNITS
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR
from gainfarm.schemas.robot import JOINT_NAMES, ModelSpec

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


def trajectories_text(config: RunConfig) -> str:
    """The run's trajectories and their duration: 'spiral 5 s', 'spiral, random, pyramid 3 s'."""
    kinds = [trajectory.kind for trajectory in config.trajectories]
    durations = {trajectory.duration for trajectory in config.trajectories}
    if len(durations) == 1:
        return f"{', '.join(kinds)} {durations.pop():g} s"
    return ", ".join(f"{t.kind} {t.duration:g} s" for t in config.trajectories)


def run_title(config: RunConfig) -> str:
    """A run's figures' title: what it was tuned on (trajectories and their duration, plant,
    population), then how."""
    return (
        f"{config.mode} controller on {trajectories_text(config)}, {plant_text(config.model)}, "
        f"population {config.pop}\n{_search(config)}, seed {config.seed}"
    )


def run_setup(config: RunConfig) -> list[str]:
    """A run's configuration as its report lists it."""
    trajectories = ", ".join(
        f"{trajectory.kind} {trajectory.duration:g} s" for trajectory in config.trajectories
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


UNITS_LINE = (
    f"Units: kp in {UNITS['kp']} and kd in {UNITS['kd']}, one per joint "
    f"{JOINT_NAMES[0]}..{JOINT_NAMES[-1]}; f_acc is the mean end-effector error (front.csv: m; "
    "here: mm), f_t the mean squared torque change per 2 ms tick in (N·m)²."
)
DIVERGED_NOTE = (
    "*diverged*: an episode of the member was stopped early; every tick it did not run is "
    f"charged {DIVERGED_TICK_ERROR:g} m of error and the largest possible torque change, so its "
    "f_acc and f_t are a penalty, not a measurement (its mean error can exceed the largest error "
    "measured)."
)


def shown(member: FrontMember) -> tuple[str, str, bool]:
    """A member's scores as the report shows them: members alike here share a line."""
    return (f"{member.f_acc * 1000:.3f}", f"{member.f_t:.4g}", member.diverged)


def _error(member: FrontMember | Baseline) -> str:
    """f_acc in mm, marked when it is a divergence penalty."""
    return f"{member.f_acc * 1000:.3f}" + (" *diverged*" if member.diverged else "")


def front_table_row(rank: int, member: FrontMember, count: int = 1) -> str:
    """One line of the report's front table (public so a test or a caller can find it): the
    member at front.csv row `rank`, and how many members from there on share its scores."""
    rows = f"{count} (rows {rank}-{rank + count - 1})" if count > 1 else "1"
    return f"| {rank} | {_error(member)} | {member.f_t:.4g} | {rows} | {gains_text(member)} |"


PICK_NAMES = {"knee": "**knee** (use this)", "accurate": "most accurate", "smooth": "smoothest"}


def _dominates(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[0] <= b[0] and a[1] <= b[1] and a != b


def baseline_text(front: Sequence[FrontMember], baseline: Baseline, knee: FrontMember) -> str:
    """How the front fares against the default gains, in one sentence."""
    if baseline.diverged:
        return "The default gains diverged on these trajectories: their scores are a penalty."
    better = sum(
        1 for m in front if not m.diverged and _dominates(m.objectives, baseline.objectives)
    )
    text = (
        f"{better} of the front's {len(front)} members dominate the default gains (as accurate "
        "and as smooth, and better in one)"
    )
    if _dominates(baseline.objectives, knee.objectives):
        text += "; the default gains dominate the knee: the run has not beaten them there yet"
    return text + "."


def controllers_section(
    picks: Sequence[Pick],
    baseline: Baseline | None,
    run_dir: str = "RUN",
    front: Sequence[FrontMember] = (),
) -> list[str]:
    """The report's answer to "which controller?": the knee, the most accurate and the
    smoothest member with their gains, beside the default gains and how the front fares
    against them; how the knee is chosen, and how to take it out of the run."""
    lines = ["## The controller to use", ""]
    if not picks:
        return [*lines, "No front yet.", ""]
    lines += [
        f"| | front.csv row | f_acc (mm) | f_t ((N·m)²) | kp ({UNITS['kp']}) "
        f"{JOINT_NAMES[0]}..{JOINT_NAMES[-1]} | kd ({UNITS['kd']}) |",
        "|---|---:|---:|---:|---|---|",
    ]
    for chosen in picks:
        member = chosen.member
        shared = f" ({chosen.sharing} members share it)" if chosen.sharing > 1 else ""
        lines.append(
            f"| {PICK_NAMES[chosen.name]} | {chosen.row}{shared} | {_error(member)} | "
            f"{member.f_t:.4g} | {' '.join(f'{g:.4g}' for g in member.kp)} | "
            f"{' '.join(f'{g:.4g}' for g in member.kd)} |"
        )
    if baseline is not None:
        lines.append(
            f"| default gains (not tuned) | – | {_error(baseline)} | {baseline.f_t:.4g} | "
            f"{' '.join(f'{g:.4g}' for g in baseline.gains.kp)} | "
            f"{' '.join(f'{g:.4g}' for g in baseline.gains.kd)} |"
        )
    if baseline is not None and front:
        lines += ["", baseline_text(front, baseline, picks[0].member)]
    lines += [
        "",
        "The knee is the member whose worse objective is the least bad once both are taken on a "
        "log scale (a front spans decades in each) and normalised between the front's ideal and "
        "nadir points: the minimum of pymoo's achievement scalarisation function with equal "
        "weights, ties to the lowest row; diverged members are never picked unless all are. It "
        "gives up neither accuracy nor smoothness for the other.",
        "",
        f"Take it out of the run: `analytic export {run_dir}` writes its gains as JSON (which "
        "`analytic batch --gains` and `worker episode --gains` read); `--format ros2_control` "
        "as a ros2_control controller configuration; `--member accurate|smooth|N` another "
        "member (N: its front.csv row).",
        "",
        UNITS_LINE,
        "",
    ]
    return lines


def report_markdown(
    *,
    title: str,
    config_lines: Sequence[str],
    history: Sequence[HistoryRow],
    front: Sequence[FrontMember],
    converged: str,
    picks: Sequence[Pick] = (),
    baseline: Baseline | None = None,
    run_dir: str = "RUN",
    validation: ValidationRecord | None = None,
) -> str:
    """The text of report.md (see `write_report`)."""
    lines = [f"# {title}", ""]
    if picks:
        lines += controllers_section(picks, baseline, run_dir, front)
    lines += ["## Configuration", ""]
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
    groups = point_groups(members, shown)
    points = (
        f", {len(groups)} distinct at the precision shown" if len(groups) != len(members) else ""
    )
    lines += ["", f"## Pareto front ({len(members)} members{points}, most accurate first)", ""]
    if members:
        lines += [
            "Members whose scores agree to the precision shown share one line (the first one's "
            "gains are shown; front.csv lists each, at full precision).",
            "",
            "| # (front.csv row) | f_acc (mm) | f_t ((N·m)²) | members | gains: kp "
            f"({UNITS['kp']}) / kd ({UNITS['kd']}), {JOINT_NAMES[0]}..{JOINT_NAMES[-1]} |",
            "|---:|---:|---:|---:|---|",
            *(front_table_row(row, members[row - 1], count) for row, count in groups),
        ]
        if any(member.diverged for member in members):
            lines += ["", DIVERGED_NOTE]
        lines += ["", UNITS_LINE]
    else:
        lines.append("No members yet.")
    if validation is not None:
        lines += ["", *validation_section(validation, members)]

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
    picks: Sequence[Pick] = (),
    baseline: Baseline | None = None,
    run_dir: str = "RUN",
    validation: ValidationRecord | None = None,
) -> None:
    """A short report.md at `path`: the controller to use (`picks`, beside the default gains'
    `baseline`; `run_dir` for the export command it shows), configuration, summary, the front
    as a table (members with identical scores on one line), the figures.

    `converged` is the caller's one-line verdict on why the run stopped (or that it has not),
    e.g. "converged after 240 evaluations (hypervolume gain < 0.1% over 3 generations)". The
    figures and CSVs are linked by their standard names relative to the report, so write them
    into the same directory. The table is rounded for reading; front.csv holds the exact values.
    """
    text = report_markdown(
        title=title,
        config_lines=config_lines,
        history=history,
        front=front,
        converged=converged,
        picks=picks,
        baseline=baseline,
        run_dir=run_dir,
        validation=validation,
    )
    write_atomically(Path(path), text.encode("utf-8"))


def validation_section(validation: ValidationRecord, members: Sequence[FrontMember]) -> list[str]:
    """How far the front can be trusted: what the referee checked and found, the workers it
    caught with the evidence, and each member's workers and checks (provenance.csv: each
    episode)."""
    lines = ["## Validation", ""]
    if validation.unchecked:
        lines += [f"Not checked: {validation.unchecked}.", ""]
    else:
        rate = f" (rate {validation.spot_check_rate:g})" if validation.spot_check_rate else ""
        lines += [
            f"- episodes the referee (this process) ran again: {validation.refereed} of the "
            f"front's, {validation.spot_checked} spot checks{rate}",
            f"- disagreements: {validation.disagreements}; could not be rerun (failed): "
            f"{validation.unsettled}",
        ]
        for worker, evidence in sorted(validation.distrusted.items()):
            lines.append(f"- distrusted: {worker}, which {evidence}")
        if validation.rewinds:
            lines.append(
                f"- the evolution started again {validation.rewinds} time(s) without the "
                "distrusted workers' results, which ran again elsewhere"
            )
        lines.append("")
    if members and any(member.episodes for member in members):
        lines += ["| # (front.csv row) | workers | episodes: how checked |", "|---:|---|---|"]
        for row, member in enumerate(members, start=1):
            workers = ", ".join(sorted({e.worker for e in member.episodes})) or "-"
            checks = Counter(
                f"{e.check}, {e.ruling}" if e.check != "not checked" else e.check
                for e in member.episodes
            )
            how = "; ".join(f"{count} {check}" for check, count in sorted(checks.items()))
            lines.append(f"| {row} | {workers} | {how} |")
        lines += ["", f"Each episode: [{PROVENANCE_CSV}]({PROVENANCE_CSV})."]
    return lines[:-1] if lines[-1] == "" else lines


def plant_text(model: ModelSpec) -> str:
    """Which plant a run simulated: a named one, or a custom one, and its joints."""
    name = plant_name(model)
    if name == "custom":
        return f"custom plant (see config.json), {model.joints} joints"
    return f"{name} plant, {model.joints} joints"
