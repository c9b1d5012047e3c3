"""Reports in plain words: a run's report.md (each experiment words its own:
analytic.experiments).

Like the figures, edge code on plain data: the caller computes, these functions only say it.
"""

import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import (
    column_title,
    declarations,
    number_text,
    point_text,
    shown_unit,
    value_text,
)
from gainfarm.analytic.tuning.picks import dominating, shortfall
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
from gainfarm.cli.words import counted
from gainfarm.edges.files import write_atomically
from gainfarm.models import robot_of
from gainfarm.plugins import PluginError
from gainfarm.schemas.controller import UNITS
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR
from gainfarm.schemas.robot import JOINT_NAMES, PlantSpec

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
        f"{config.mode} controller on {trajectories_text(config)}, {plant_text(config.plant)}, "
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
        else f"; objectives averaged with weights {config.objectives[0]} "
        + " / ".join(f"{w:.2f}" for w, _ in weights)
        + f", {config.objectives[1]} "
        + " / ".join(f"{w:.2f}" for _, w in weights)
    )
    first = declarations(config.objectives)[0]  # the reference point is in its unit
    robust = ""
    if config.plants:
        robust = (
            f"; robust: scored on it and {len(config.plants)} plant variants (config.json's "
            f"plants), each trajectory's objectives their {AGGREGATE_TEXT[config.aggregate]}"
        )
    return [
        f"{controller} on {trajectories}{averaged}",
        f"{_search(config)}, population {config.pop}, seed {config.seed}",
        f"{plant_text(config.plant)}{robust}; reference point "
        f"{config.objectives[0]} {config.reference_point[0]} {first.unit}".rstrip()
        + ", "
        f"{config.objectives[1]} {config.reference_point[1]}",
        arm_text(config.plant),
    ]


def arm_text(plant: PlantSpec) -> str:
    """The arm a plant is of, as a report says it: its joints, and its torque interface (what
    the robot does with a torque command, and whether the plant has it add gravity)."""
    try:
        robot = robot_of(plant)
    except PluginError:
        return f"arm {plant.robot} (not installed here)"
    joints, interface = robot.joint_names, robot.torque_interface
    adds = (
        "adding its own gravity model under the command"
        if plant.interface == "fri"
        else "without gravity compensation (interface torque: the command is the motor torque)"
    )
    return (
        f"arm {robot.name}: {counted(len(joints), 'joint')} ({joints[0]}..{joints[-1]}), "
        f"behind {interface.name} ({interface.description}), simulated {adds}"
    )


AGGREGATE_TEXT = {
    "mean": "mean",
    "worst": "worst",
    "cvar": "CVaR (the mean of the worst quarter)",
}


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
    """A member's gains on one short line: 'kp 2000 2000 1200 … / kd 20 20 15 …'."""
    kp = " ".join(f"{gain:.4g}" for gain in member.kp)
    kd = " ".join(f"{gain:.4g}" for gain in member.kd)
    return f"kp {kp} / kd {kd}"


def units_line(
    names: Sequence[str] = DEFAULT_OBJECTIVES, joints: Sequence[str] = JOINT_NAMES
) -> str:
    """What the report's numbers are, for an arm of `joints` (the default arm's, the iiwa 14's,
    unless said): the paper's objectives, or each objective's declaration."""
    gains = (
        f"Units: kp in {UNITS['kp']} and kd in {UNITS['kd']}, one per joint "
        f"{joints[0]}..{joints[-1]}"
    )
    if tuple(names) == DEFAULT_OBJECTIVES:
        return (
            f"{gains}; f_acc is the mean end-effector error (front.csv: m; here: mm), f_t the "
            "mean squared torque change per 2 ms tick in (N·m)²."
        )
    said = "; ".join(
        f"{o.name} is the {o.description}, in {o.unit}"
        + (f" (here: {shown_unit(o)[0]})" if shown_unit(o)[0] != o.unit else "")
        if o.unit
        else f"{o.name}: {o.description}"
        for o in declarations(names)
    )
    return f"{gains}; {said}."


def diverged_note(names: Sequence[str] = DEFAULT_OBJECTIVES) -> str:
    """What *diverged* means, naming the run's objectives."""
    return (
        "*diverged*: an episode of the member was stopped early; every tick it did not run is "
        f"charged {DIVERGED_TICK_ERROR:g} m of error and the largest possible torque change, so "
        f"its {' and '.join(names)} are a penalty, not a measurement (its mean error can exceed "
        "the largest error measured)."
    )


DIVERGED_NOTE = diverged_note()


def shown(member: FrontMember) -> tuple[str, ...]:
    """A member's scores as the report shows them: members alike here share a line."""
    return (*_numbers(member), str(member.diverged))


def _numbers(point: FrontMember | Baseline) -> list[str]:
    named = point.named
    return [number_text(o, named[o.name]) for o in declarations(tuple(named))]


def _cells(point: FrontMember | Baseline) -> str:
    """Its objectives as a table's cells, the first marked when they are a divergence penalty."""
    numbers = _numbers(point)
    numbers[0] += " *diverged*" if point.diverged else ""
    return " | ".join(numbers)


def _titles(names: Sequence[str]) -> str:
    """The objectives' columns' titles: "f_acc (mm) | f_t ((N·m)²)"."""
    return " | ".join(column_title(o) for o in declarations(names))


def front_table_row(rank: int, member: FrontMember, count: int = 1) -> str:
    """One line of the report's front table (public so a test or a caller can find it): the
    member at front.csv row `rank`, and how many members from there on share its scores."""
    rows = f"{count} (rows {rank}-{rank + count - 1})" if count > 1 else "1"
    return f"| {rank} | {_cells(member)} | {rows} | {gains_text(member)} |"


PICK_NAMES = {
    "recommended": "**recommended** (use this)",
    "closest": "closest to dominating the defaults (not recommended)",
    "knee": "knee of the whole front",
    "accurate": "most accurate",
    "smooth": "smoothest",
}
DOMINATING_SHOWN = 10  # the members listed as dominating the defaults; the rest are counted


def _scores(point: FrontMember | Baseline) -> str:
    return point_text(point)


def recommendation_text(picks: Sequence[Pick], baseline: Baseline | None) -> str:
    """The report's first line: which member to use and why, or that none is recommended, what
    to do instead and which member comes closest (`picks`: `analytic.tuning.picks.picks` given
    `baseline`)."""
    first = picks[0]
    member = first.member
    if first.name == "recommended" and baseline is not None and baseline.diverged:
        return (
            f"**Use front.csv row {first.row}** ({_scores(member)}): the default "
            "gains diverged on the run's trajectories, so every member that finished its "
            "episodes beats them, and this is the knee among those."
        )
    if first.name == "recommended" and baseline is not None:
        return (
            f"**Use front.csv row {first.row}** ({_scores(member)}): it dominates "
            f"the default gains ({_scores(baseline)}) on the run's trajectories, as "
            "accurate and as smooth and better in one, and is the knee among the members that do."
        )
    if first.name == "closest" and baseline is not None:
        return (
            "**No member of the front dominates the default gains** "
            f"({_scores(baseline)}) on the run's trajectories, so none is "
            "recommended: keep the default gains, or run longer (more evaluations, a larger "
            f"population). Closest to dominating them: row {first.row} "
            f"({_scores(member)}), whose worse objective is "
            f"{10 ** shortfall(member, baseline):#.3g} times the defaults' (the least of any "
            "member)."
        )
    return (
        "**The default gains were not scored for this run** (no baseline.json), so no member is "
        f"known to beat them and none is recommended; the knee of the front is row {first.row}."
    )


def dominating_text(
    front: Sequence[FrontMember], baseline: Baseline, picks: Sequence[Pick]
) -> list[str]:
    """The members that dominate the default gains, the first `DOMINATING_SHOWN` as a table and
    the rest counted; and whether the knee of the whole front is one of them."""
    members = sorted_front(front)
    rows = dominating(members, baseline)
    if not rows:
        return []
    whom = (
        "finish their episodes, which the default gains did not"
        if baseline.diverged
        else "dominate the default gains"
    )
    lines = [
        f"{len(rows)} of the front's {counted(len(members), 'member')} {whom}:",
        "",
        f"| front.csv row | {_titles(members[0].names)} |",
        "|---:|---:|---:|",
        *(f"| {i + 1} | {_cells(members[i])} |" for i in rows[:DOMINATING_SHOWN]),
    ]
    if rest := rows[DOMINATING_SHOWN:]:
        lines += ["", f"and {len(rest)} more, between rows {rest[0] + 1} and {rest[-1] + 1}."]
    knee = next((chosen for chosen in picks if chosen.name == "knee"), None)
    if knee is not None and knee.row - 1 not in rows:
        lines += [
            "",
            f"The knee of the whole front (row {knee.row}) is not one of them: it gives up "
            "accuracy or smoothness against the default gains.",
        ]
    return lines


def controllers_section(
    picks: Sequence[Pick],
    baseline: Baseline | None,
    run_dir: str = "RUN",
    front: Sequence[FrontMember] = (),
    joints: Sequence[str] = JOINT_NAMES,
) -> list[str]:
    """The report's answer to "which controller?": the recommended member (or the one closest
    to it), the knee, the most accurate and the smoothest member with their gains, beside the
    default gains; the members that dominate the defaults; how the picks are chosen, and how to
    take one out of the run. `picks` are `analytic.tuning.picks.picks(front, baseline)`;
    `joints` the arm's (the default arm's, the iiwa 14's, unless said)."""
    lines = ["## The controller to use", ""]
    if not picks:
        return [*lines, "No front yet.", ""]
    names = picks[0].member.names
    lines += [
        f"| | front.csv row | {_titles(names)} | kp ({UNITS['kp']}) "
        f"{joints[0]}..{joints[-1]} | kd ({UNITS['kd']}) |",
        "|---|---:|---:|---:|---|---|",
    ]
    for chosen in picks:
        member = chosen.member
        shared = f" ({chosen.sharing} members share it)" if chosen.sharing > 1 else ""
        lines.append(
            f"| {PICK_NAMES[chosen.name]} | {chosen.row}{shared} | {_cells(member)} | "
            f"{' '.join(f'{g:.4g}' for g in member.kp)} | "
            f"{' '.join(f'{g:.4g}' for g in member.kd)} |"
        )
    if baseline is not None:
        lines.append(
            f"| default gains (not tuned) | – | {_cells(baseline)} | "
            f"{' '.join(f'{g:.4g}' for g in baseline.gains.kp)} | "
            f"{' '.join(f'{g:.4g}' for g in baseline.gains.kd)} |"
        )
    if baseline is not None and baseline.diverged:
        lines += [
            "",
            "The default gains diverged on these trajectories: their scores are a penalty.",
        ]
    if baseline is not None and front:
        lines += ["", *dominating_text(front, baseline, picks)]
    lines += [
        "",
        "The knee is the member whose worse objective is the least bad once both are taken on "
        "a log scale (a front spans decades in each) and normalised between the front's ideal "
        "and nadir points: the minimum of pymoo's achievement scalarisation function with equal "
        "weights, ties to the lowest row; it gives up neither accuracy nor smoothness for the "
        "other. The recommended member is the knee among the members that dominate the default "
        "gains (as accurate and as smooth on the run's trajectories, scored as the run scored "
        "every candidate, and better in one): of those, the one that measure ranks best, so "
        "the knee itself whenever it dominates them. When no member dominates the defaults, "
        "the closest to dominating them is the one whose worse objective is the smallest "
        "multiple of the defaults'. Diverged members are never picked unless all are.",
        "",
        f"Take it out of the run: `analytic export {run_dir}` writes the recommended member's "
        "gains as JSON (which `analytic batch --gains` and `worker episode --gains` read), and "
        "refuses when none is recommended; `--format ros2_control` as a ros2_control controller "
        "configuration; `--member knee|accurate|smooth|N` another member (N: its front.csv "
        "row).",
        "",
        units_line(names, joints),
        "",
    ]
    return lines


def stopped_text(why: str) -> str:
    """Why a run stopped, as the report's Summary and the terminal say it: "stopped after 4
    generations", "stopped: converged after 240 evaluations (...)"."""
    if why[:1].isdigit():  # a budget spent: "4 generations", "24 evaluations"
        return f"stopped after {why}"
    return why if why.startswith("stopped") else f"stopped: {why}"


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
    advice: str | None = None,
    joints: Sequence[str] = JOINT_NAMES,
) -> str:
    """The text of report.md (see `write_report`)."""
    lines = [f"# {title}", ""]
    if picks:  # first the recommendation: what to use, or that nothing here beats the defaults
        lines += [advice or recommendation_text(picks, baseline), ""]
        lines += controllers_section(picks, baseline, run_dir, front, joints)
    lines += ["## Configuration", ""]
    lines += [f"- {line}" for line in config_lines] or ["- (none given)"]
    lines += ["", "## Summary", ""]
    if history:
        last = history[-1]
        lines += [
            f"- generations: {len(history)}",
            f"- evaluations: {last.evaluations}",
            f"- final hypervolume: {last.hypervolume:.6g}",
            "- "
            + "; ".join(
                f"best {o.name}: {value_text(o, best)}"
                for o, best in zip(declarations(last.names), last.best, strict=True)
            ),
            f"- wall time: {_duration(last.wall_seconds)}",
        ]
    else:
        lines.append("- no generation finished yet")
    if converged:
        lines.append(f"- {stopped_text(converged)}")

    members = sorted_front(front)
    groups = point_groups(members, shown)
    points = (
        f", {len(groups)} distinct at the precision shown" if len(groups) != len(members) else ""
    )
    lines += [
        "",
        f"## Pareto front ({counted(len(members), 'member')}{points}, most accurate first)",
        "",
    ]
    if members:
        lines += [
            "Members whose scores agree to the precision shown share one line (the first one's "
            "gains are shown; front.csv lists each, at full precision).",
            "",
            f"| # (front.csv row) | {_titles(members[0].names)} | members | gains: kp "
            f"({UNITS['kp']}) / kd ({UNITS['kd']}), {joints[0]}..{joints[-1]} |",
            "|---:|---:|---:|---:|---|",
            *(front_table_row(row, members[row - 1], count) for row, count in groups),
        ]
        if any(member.diverged for member in members):
            lines += ["", diverged_note(members[0].names)]
        lines += ["", units_line(members[0].names, joints)]
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
    advice: str | None = None,
    joints: Sequence[str] = JOINT_NAMES,
) -> None:
    """A short report.md at `path`: first the recommendation (`advice`, the held-out check's, if
    given; else the recommended member, or that none dominates the default gains), then the
    controller to use (`picks`, computed beside the default gains' `baseline`; `run_dir` for the
    export command it shows), configuration,
    summary, the front as a table (members with identical scores on one line), the figures.
    `joints`: the arm's joint names, which the gains are of (the iiwa 14's unless said).

    `converged` is the caller's one line on why the run stopped (or that it has not),
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
        advice=advice,
        joints=joints,
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
        rate = f" (rate {validation.spot_check_rate:.3g})" if validation.spot_check_rate else ""
        more = [
            f"{counted(count, what)}{where}"
            for count, what, where in (
                (validation.failures_checked, "failure", " its worker claimed"),
                (validation.baseline_refereed, "episode", " of the default gains'"),
                (validation.held_out_refereed, "episode", " of the held-out check's"),
            )
            if count
        ]
        lines += [
            f"- episodes the referee (this process) ran again: {validation.refereed} of the "
            f"front's, {counted(validation.spot_checked, 'spot check')}{rate}"
            + "".join(f", {item}" for item in more),
            f"- disagreements: {validation.disagreements}; could not be rerun (failed): "
            f"{validation.unsettled}",
        ]
        if validation.spot_check_guarantee:
            lines.append(f"- spot checks: {validation.spot_check_guarantee}")
        for worker, evidence in sorted(validation.distrusted.items()):
            lines.append(f"- distrusted: {worker}, which {evidence}")
        if validation.rewinds:
            lines.append(
                f"- the evolution started again {counted(validation.rewinds, 'time')} without the "
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


def plant_text(plant: PlantSpec) -> str:
    """Which plant a run simulated: its arm, a named plant or a custom one, and its joints."""
    name = plant_name(plant)
    if name == "custom":
        return f"{plant.robot}, custom plant (see config.json), {plant.joints} joints"
    return f"{plant.robot}, {name} plant, {plant.joints} joints"
