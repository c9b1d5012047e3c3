"""The controller to use from a run, and the files that carry it out of the run.

A run's front offers many controllers; `picks` names them: the recommended member (the best
compromise among those that dominate the default gains: what `controller` takes unless told
otherwise), the knee (the best compromise of the whole front), the most accurate and the
smoothest. `controller` makes any member a `schemas.controller.Controller`
(gains, the arm's joints, units, what it assumes of the arm, objectives, provenance) and `render`
writes it as JSON (what `analytic batch --gains` and `worker episode --gains` read), as the same
document in YAML, or as a ros2_control parameter file naming the arm's joints. The arm is the
run's (its plant's robot), looked up here: a run of an arm not installed (nor registered from
its description file, `--robot FILE`) is refused in one line.

The picks are gainfarm.analytic.tuning.picks' (one rule for every reader of a run).
"""

import hashlib
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path

import yaml
from pydantic import ValidationError

from gainfarm.analytic.tuning.check import advice_in, read_check
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import declarations, point_text
from gainfarm.analytic.tuning.picks import Advice, Pick, pick_at, picks
from gainfarm.analytic.tuning.records import (
    BASELINE_JSON,
    CONFIG_JSON,
    FRONT_CSV,
    FRONT_JSON,
    HISTORY_CSV,
    MAX_RECORD_BYTES,
    RUN_JSON,
    Baseline,
    FrontMember,
    read_baseline,
    read_front,
    read_front_json,
    read_history,
    read_identity,
    sorted_front,
)
from gainfarm.cli.words import counted
from gainfarm.models import PlantError, plant_preset, resolve, robot_of
from gainfarm.plugins import PluginError
from gainfarm.schemas.controller import (
    Assumptions,
    Controller,
    HeldOut,
    Member,
    ObjectiveValue,
    Source,
)
from gainfarm.schemas.documents import read_bounded
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.limits import MEASURED
from gainfarm.schemas.robot import PLANTS, PlantSpec, Robot
from gainfarm.schemas.wire import one_line

MEMBERS = ("recommended", "knee", "accurate", "smooth")
FORMATS = ("json", "yaml", "ros2_control")
RULES = {
    "recommended": "the first member, in the knee's order among those that dominate the default "
    "gains as the run scored them (baseline.json), that holds against them on the held-out "
    "check (check.json); a run without a check: the first of those",
    "knee": "the knee: least worse normalised objective (pymoo ASF, equal weights; both "
    "objectives on a log scale, normalised between the front's ideal and nadir)",
    "accurate": "the most accurate member (smallest f_acc)",
    "smooth": "the smoothest member (smallest f_t)",
    "row": "the member at this row of front.csv",
}
# The ros2_control controller's name, and the controller manager's rate: the episodes' 500 Hz.
ROS2_CONTROLLER = "pd_effort_controller"


class BadRun(ValueError):
    """A directory that holds no run, or no front yet."""


class BadMember(ValueError):
    """A --member that names no member of the front."""


def plant_name(plant: PlantSpec) -> str:
    """realistic, plain or ideal if `plant` is that plant of its robot (whatever its joints),
    with its per-joint numbers left to the robot or written out (a run's config resolves them);
    else custom."""
    for name in PLANTS:
        try:
            named = plant_preset(name, plant.robot).model_copy(update={"joints": plant.joints})
            if resolve(plant) == resolve(named):
                return name
        except (PluginError, PlantError, ValueError):  # a robot not here, a plant it cannot be
            return "custom"
    return "custom"


def run_robot(plant: PlantSpec) -> Robot:
    """The arm a run's `plant` names; BadRun, in one line, if it is not installed here."""
    try:
        return robot_of(plant)
    except PluginError as error:
        raise BadRun(
            f"its arm {plant.robot!r} is not here ({error}); a robot of your own: give its "
            "description file, --robot FILE"
        ) from None


def pick(
    front: Sequence[FrontMember],
    which: str,
    baseline: Baseline | None = None,
    advice: Advice | None = None,
) -> Pick:
    """The member `which` names: recommended (beside the default gains' `baseline`), knee,
    accurate, smooth, or a row of front.csv (1-based). BadMember if there is none such."""
    front = sorted_front(front)
    others = f"knee, accurate, smooth or a row of front.csv (1-{len(front)})"
    if which in MEMBERS:
        named = {chosen.name: chosen for chosen in picks(front, baseline, advice)}
        if which in named:
            return named[which]
        if baseline is None:
            raise BadMember(
                "recommended (the default) compares the front with the default gains' scores, "
                f"and the run has no {BASELINE_JSON} of them (stopped before it scored them, or "
                f"scored before they changed); name one: {others}"
            )
        if advice is not None:
            raise BadMember(
                "recommended (the default): on the held-out check no member held against the "
                f"default gains (closest: row {named['closest'].row}, report.md), so none is "
                f"recommended; keep the default gains, or name one: {others}"
            )
        raise BadMember(
            "recommended (the default): no member of the front dominates the default gains "
            f"({point_text(baseline)}), so none is "
            f"recommended (closest: row {named['closest'].row}, report.md); keep the default "
            f"gains, run longer, or name one: {others}"
        )
    try:
        row = int(which)
    except ValueError:
        raise BadMember(f"expected recommended, {others}, got {which!r}") from None
    if not 1 <= row <= len(front):
        raise BadMember(
            f"row {row} is out of range: front.csv has {counted(len(front), 'member')} "
            f"(1-{len(front)})"
        )
    return pick_at(front, "row", row - 1)


def joints_of(plant: PlantSpec, count: int | None = None) -> tuple[str, ...]:
    """The joint names of the arm `plant` names. If it is not installed here (a run of another
    machine's arm) or has not `count` joints (the gains a member has), `count` joints numbered
    from 1, so that the gains still show."""
    try:
        names = robot_of(plant).joint_names
    except PluginError:
        names = ()
    if count is None or len(names) == count:
        return names
    return tuple(f"joint{k}" for k in range(1, count + 1))


def baseline_of(directory: Path, defaults: PDGains) -> Baseline | None:
    """The default gains' scores in the run at `directory` (baseline.json); None if it has none,
    or one that is unreadable or of other gains than `defaults`, its arm's (a run's `baseline`
    would score them again)."""
    try:
        found = read_baseline(Path(directory) / BASELINE_JSON)
    except (OSError, ValueError):
        return None
    return found if found.gains == defaults else None


def controller(directory: Path, which: str = "recommended") -> Controller:
    """Front member `which` of the run in `directory` as a Controller. BadRun if the directory
    holds no run or no front yet, BadMember if `which` names no member."""
    directory = Path(directory)
    try:
        config_bytes = read_bounded(directory / CONFIG_JSON, MAX_RECORD_BYTES)
    except OSError:
        raise BadRun(f"{str(directory)!r} holds no run (no {CONFIG_JSON})") from None
    try:
        config = RunConfig.model_validate_json(config_bytes)
        front_bytes = (directory / FRONT_CSV).read_bytes()
        front = read_front(directory / FRONT_CSV)
        history = read_history(directory / HISTORY_CSV)
        identity = read_identity(directory / RUN_JSON) if (directory / RUN_JSON).exists() else None
    except FileNotFoundError:
        raise BadRun(f"{str(directory)!r} has no front yet: no generation has finished") from None
    except (OSError, ValueError, ValidationError) as error:
        raise BadRun(f"{str(directory)!r}: unreadable run ({one_line(error)})") from None
    if not front:
        if history:
            raise BadRun(
                f"{str(directory)!r} has an empty front: no candidate has kept to the safety "
                "limits yet (report.md says which ones they broke)"
            )
        raise BadRun(f"{str(directory)!r} has no front yet: no generation has finished")
    robot = run_robot(config.plant)
    chosen = pick(front, which, baseline_of(directory, robot.default_gains), advice_in(directory))
    member = chosen.member
    measured = _measures(directory, member)
    if measured and config.limits.violated(measured):  # a front from before the limits
        raise BadMember(
            f"that member breaks the run's safety limits "
            f"({', '.join(config.limits.violated(measured))}): not a controller to use"
        )
    evaluations = history[-1].evaluations if history else 0
    return Controller(
        joints=robot.joint_names,
        kp=member.kp,
        kd=member.kd,
        member=Member(
            selected=chosen.name if chosen.name != "row" else f"row {chosen.row}",
            row=chosen.row,
            rule=RULES[chosen.name],
            f_acc=member.named.get("f_acc"),
            f_t=member.named.get("f_t"),
            objectives=_objective_values(member),
            diverged=member.diverged,
            sharing=chosen.sharing,
            measures=dict(zip(MEASURED, measured, strict=False)) if measured else None,
            held_out=_held_out(directory, member),
        ),
        limits=config.limits if measured else None,
        assumes=Assumptions.of(config.plant, robot),
        source=Source(
            run_id=identity.run_id if identity is not None else "",
            directory=str(directory),
            config_sha256=hashlib.sha256(config_bytes).hexdigest(),
            front_sha256=hashlib.sha256(front_bytes).hexdigest(),
            trajectories=config.trajectories,
            plant=plant_name(config.plant),
            model=config.plant,
            feedforward=config.feedforward,
            objective_weights=config.objective_weights,
            population=config.pop,
            algorithm=config.algorithm,
            seed=config.seed,
            stopped=config.termination.reason([row.hypervolume for row in history], evaluations),
        ),
    )


def _held_out(directory: Path, member: FrontMember) -> HeldOut | None:
    """The held-out check of the member beside the default gains', if its run checked it."""
    record = read_check(directory)
    items = (record or {}).get("controllers", ())
    default = next((item for item in items if item["row"] is None), {})
    for item in items:
        if tuple(item["kp"]) == member.kp and tuple(item["kd"]) == member.kd:
            fields = {name: item[name] for name in HeldOut.model_fields if name in item}
            if "advice" in record:  # type: ignore[operator]
                fields["recommended"] = item["name"] == "recommended"
            return HeldOut(
                plants=record["plants"],  # type: ignore[index]
                default_median_f_acc=default.get("median_f_acc"),
                default_worst_f_acc=default.get("worst_f_acc"),
                **fields,
            )
    return None


def _measures(directory: Path, member: FrontMember) -> tuple[float, ...]:
    """The member's safety measures as front.json keeps them (none from a run before them)."""
    try:
        members = read_front_json(directory / FRONT_JSON)
    except (OSError, ValueError):
        return ()
    same = [m for m in members if (m.kp, m.kd) == (member.kp, member.kd)]
    return same[0].measures if same else ()


def render(controller: Controller, fmt: str) -> bytes:
    """The controller as `fmt`: json, yaml (the same document) or ros2_control."""
    if fmt == "json":
        return (controller.model_dump_json(indent=2) + "\n").encode()
    if fmt == "yaml":
        document = controller.model_dump(mode="json")
        return yaml.safe_dump(document, sort_keys=False, allow_unicode=True).encode()
    if fmt == "ros2_control":
        return ros2_control(controller).encode()
    raise ValueError(f"unknown format {fmt!r}: one of {', '.join(FORMATS)}")


def ros2_control(controller: Controller) -> str:
    """A ros2_control parameter file running the gains as a PD on the effort interface.

    ros2_controllers has no plain "PD on effort" controller: effort_controllers'
    JointGroupEffortController forwards torques and has no gains. The closest standard is
    joint_trajectory_controller with `command_interfaces: [effort]`: it then runs a PID per
    joint, u = p·e + i·∫e + d·(q̇_ref − q̇) + ff_velocity_scale·q̇_ref, which with i = 0 and
    ff_velocity_scale = 0 is the episodes' PD law. Every gain is written as a float: ROS 2
    parameters are typed, and an integer would be refused for these doubles. The joints are the
    controller's (the arm's joint names, as its ROS 2 description names them).
    """
    member, source = controller.member, controller.source
    trajectories = ", ".join(f"{t.kind} {t.duration:g} s" for t in source.trajectories)
    parameters = {
        "controller_manager": {
            "ros__parameters": {
                "update_rate": round(1 / controller.control_period),
                "joint_state_broadcaster": {
                    "type": "joint_state_broadcaster/JointStateBroadcaster"
                },
                ROS2_CONTROLLER: {"type": "joint_trajectory_controller/JointTrajectoryController"},
            }
        },
        ROS2_CONTROLLER: {
            "ros__parameters": {
                "joints": list(controller.joints),
                "command_interfaces": ["effort"],
                "state_interfaces": ["position", "velocity"],
                "gains": {
                    joint: {"p": float(p), "d": float(d), "i": 0.0, "ff_velocity_scale": 0.0}
                    for joint, p, d in zip(
                        controller.joints, controller.kp, controller.kd, strict=True
                    )
                },
            }
        },
    }
    diverged = " (diverged: the scores are a penalty)" if member.diverged else ""
    # A member chosen by its row is "row N" already: the row is said once.
    picked = "" if member.selected == f"row {member.row}" else f": {member.selected}"
    header = textwrap.wrap(
        f"ros2_control parameters: {source.model.robot}'s joint PD gains tuned by gainfarm, run "
        "on the effort interface by joint_trajectory_controller (its PID with i = 0 is a PD).",
        100,
        initial_indent="# ",
        subsequent_indent="# ",
    )
    header += [
        f"# Run {source.run_id or '(no run id)'} ({source.directory}), front.csv row "
        f"{member.row}{picked}.",
        f"# Tuned on {trajectories}, {source.plant} plant: {member_text(member)}{diverged}.",
        "# p in N·m/rad, d in N·m·s/rad; the episodes ran the law at "
        f"{round(1 / controller.control_period)} Hz, as update_rate does here.",
    ]
    assumes = controller.assumes or _assumptions(controller)
    header.append("# What it assumes (the JSON's `assumes` says the same):")
    interface = () if assumes.torque_interface is None else (assumes.torque_interface,)
    for fact in (
        f"joints: {assumes.joints}.",
        *(f"torque interface: {said}." for said in interface),
        f"gravity compensation: {assumes.gravity_compensation}.",
        f"feedback: {assumes.feedback}.",
        f"update rate: {assumes.update_rate_hz} Hz (update_rate below).",
    ):
        header += textwrap.wrap(fact, 100, initial_indent="# - ", subsequent_indent="#   ")
    if source.feedforward:
        header.append(
            f"# These gains were tuned on top of a learned feed-forward ({source.feedforward[:12]}"
            "), which this file does not carry."
        )
    body = yaml.safe_dump(parameters, sort_keys=False, default_flow_style=None, width=100)
    return "\n".join(header) + "\n" + body


def _assumptions(controller: Controller) -> Assumptions:
    """What a controller file from before `assumes` took for granted: its arm's, if installed
    here; else the iiwa 14's, the one arm such files were of."""
    try:
        robot = robot_of(controller.source.model)
    except PluginError:
        robot = robot_of(PlantSpec())
    return Assumptions.of(controller.source.model, robot, controller.control_period)


def point_groups(
    front: Sequence[FrontMember], key: Callable[[FrontMember], object] | None = None
) -> list[tuple[int, int]]:
    """(first row, how many) for each run of adjacent members of a sorted front whose `key`
    agrees (default: their exact scores), in order. Members with equal scores are adjacent in
    front.csv (sorted by f_acc, then f_t), and so are those whose rounded scores agree."""
    key = key or (lambda member: member.objectives)
    groups: list[tuple[int, int]] = []
    for index, member in enumerate(front):
        if groups and key(front[groups[-1][0]]) == key(member):
            groups[-1] = (groups[-1][0], groups[-1][1] + 1)
        else:
            groups.append((index, 1))
    return [(first + 1, count) for first, count in groups]


def describe_pick(chosen: Pick) -> str:
    """A pick in one short line: 'row 12 of front.csv: 12.345 mm, f_t 0.0301 (N·m)²'."""
    member = chosen.member
    shared = f", one of {chosen.sharing} members with these scores" if chosen.sharing > 1 else ""
    diverged = " (diverged: a penalty, not a measurement)" if member.diverged else ""
    return f"row {chosen.row} of front.csv: {point_text(member)}{shared}{diverged}"


def _objective_values(member: FrontMember) -> dict[str, ObjectiveValue] | None:
    """The export's `objectives`: the run's by name, unless they are the paper's pair (whose
    f_acc and f_t fields say it, as the export did before objectives could be chosen)."""
    if member.names == DEFAULT_OBJECTIVES:
        return None
    named = member.named
    return {
        o.name: ObjectiveValue(value=named[o.name], unit=o.unit, direction=o.direction)
        for o in declarations(member.names)
    }


def member_text(member: Member, name_first: bool = True) -> str:
    """An exported member's objectives as a person reads them: "f_acc 12.345 mm, f_t 0.1234
    (N·m)²" (the paper's; without "f_acc " unless `name_first`), or each objective named."""
    if member.objectives is None:
        first = "f_acc " if name_first else ""
        return f"{first}{(member.f_acc or 0.0) * 1000:.3f} mm, f_t {member.f_t:.4g} (N·m)²"
    return ", ".join(
        f"{name} {found.value:.4g} {found.unit}".strip()
        for name, found in member.objectives.items()
    )
