"""A tuned controller as a file, and the gains files the command lines read.

`analytic export RUN` writes one front member as a `Controller`: its gains, a Kp and a Kd per
joint of its arm, with the joints they belong to (the arm's own names) and their units, what it
assumes of the arm (its torque interface), its objectives, and the run it came from, as JSON or
YAML (the same document). `worker episode --gains FILE` and `analytic batch --gains FILE` read
either (`read_gains`), as `analytic batch` has always read a JSON list of {"kp": [...], "kd":
[...]} candidates; a controller of another arm's joints is refused. It lives in the contract
because the worker reads it and never imports the analytic layer.

Bad files are refused in the user's words, not pydantic's: which candidate, which gain of which
joint, and what is wrong with it.
"""

import json
import re
from typing import Any, Literal, Self

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from gainfarm.schemas.documents import BadDocument, load_json, load_yaml, quoted
from gainfarm.schemas.gains import PDGains, PerJointGains
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.robot import (
    JOINT_NAMES,
    MAX_JOINTS,
    ROBOT_PATTERN,
    PlantSpec,
    Robot,
    TorqueInterface,
)
from gainfarm.schemas.trajectory import CONTROL_PERIOD, TrajectorySpec
from gainfarm.schemas.wire import describe

FORMAT = "gainfarm-controller/1"
UNITS = {"kp": "N·m/rad", "kd": "N·m·s/rad", "f_acc": "m", "f_t": "(N·m)²"}
LAW = (
    "u = Kp (q_des − θ) + Kd (q̇_des − θ̇) per joint, every control period; θ, θ̇: the measured "
    "joint angle and velocity (motor side on the realistic plant), q_des, q̇_des: the reference; "
    "on a plant whose interface is fri (source.model.interface) u is the torque commanded on "
    "top of the robot's own gravity compensation, as its torque interface takes it "
    "(assumes.torque_interface: KUKA's FRI torque mode on the iiwa)"
)


class HeldOut(BaseModel):
    """How the member fared on plants its run never tuned on (the held-out check, check.json),
    in absolute terms beside the default gains' on the same plants."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    plants: int = Field(ge=1, description="held-out plants it ran every trajectory on")
    nominal_f_acc: float = Field(description="its mean error on the nominal plant, m")
    nominal_f_t: float | None = Field(None, description="its second objective there")
    median_f_acc: float | None = Field(
        None, description="the median over the held-out plants of its mean error, m"
    )
    worst_f_acc: float | None = Field(None, description="the largest, m")
    violations: int = Field(ge=0, description="plants on which it broke a safety limit")
    diverged: int = Field(ge=0, description="plants on which an episode diverged")
    default_median_f_acc: float | None = Field(
        None, description="the default gains' median error on the same plants, m"
    )
    default_worst_f_acc: float | None = Field(None, description="their largest, m")
    recommended: bool | None = Field(
        None, description="whether the check advises it: it holds against the default gains"
    )
    failed: tuple[str, ...] = Field((), description="why not, in words (none: it holds)")
    # From a check before it was absolute: each error over its own on the nominal plant.
    median_ratio: float | None = Field(None, exclude_if=lambda value: value is None)
    worst_ratio: float | None = Field(None, exclude_if=lambda value: value is None)


class ObjectiveValue(BaseModel):
    """One of the run's objectives for the member: its value in its own sense, and what it is."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    value: float
    unit: str = Field(description="as the objective declares it; empty when not declared")
    direction: str = Field(description="minimise or maximise")


class Member(BaseModel):
    """Which front member the gains are, and how it scored in its run."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    selected: str = Field(description="recommended, knee, accurate, smooth, or row N")
    row: int = Field(
        ge=1, description="its row in the run's front.csv (1 is the first after the header)"
    )
    rule: str = Field(description="how it was chosen")
    f_acc: float | None = Field(
        None,
        exclude_if=lambda value: value is None,
        description="mean end-effector error over the run's trajectories, m (if an objective)",
    )
    f_t: float | None = Field(
        None,
        exclude_if=lambda value: value is None,
        description="mean squared torque change per tick, (N·m)² (if an objective)",
    )
    objectives: dict[str, ObjectiveValue] | None = Field(
        None,
        exclude_if=lambda value: value is None,  # the paper's pair: f_acc and f_t say it all
        description="the run's objectives by name, when they are not the paper's f_acc and f_t",
    )
    diverged: bool = Field(description="an episode was stopped early: the scores are a penalty")
    sharing: int = Field(1, ge=1, description="front members with exactly these scores")
    measures: dict[str, float] | None = Field(
        None,
        description="its safety measures, worst over its episodes (schemas.limits); null from a "
        "run from before the limits",
    )
    held_out: HeldOut | None = Field(
        None, description="the held-out check of it, if its run checked it (check.json)"
    )


class Source(BaseModel):
    """The run the member came from: enough to find it again and to repeat its episodes."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    run_id: str
    directory: str
    config_sha256: str = Field(description="SHA-256 of the run's config.json")
    front_sha256: str = Field(description="SHA-256 of the front.csv the member is a row of")
    trajectories: tuple[TrajectorySpec, ...]
    plant: str = Field(description="realistic, ideal, or custom (see model)")
    model: PlantSpec
    feedforward: str | None = Field(
        None, description="SHA-256 of the learned model the gains were tuned on top of, if any"
    )
    objective_weights: tuple[tuple[float, float], ...] | None = None
    population: int
    algorithm: str
    seed: int
    stopped: str | None = Field(description="why the run stopped; null if it has not")


class Assumptions(BaseModel):
    """What running these gains on a robot takes for granted, said by the file rather than left
    to be guessed: which joints, whose gravity compensation, which angle is fed back, how often."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    joints: str = Field(description="which arm's joints the gains are, and in what order")
    gravity_compensation: str = Field(description="whether the robot adds its own under u")
    feedback: str = Field(description="the angle and velocity the law reads")
    update_rate_hz: int = Field(gt=0, description="how often the law runs")
    # None: a file from before the arms, whose text says KUKA's FRI (the iiwa 14's).
    torque_interface: str | None = Field(
        None,
        exclude_if=lambda value: value is None,
        description="the arm's torque interface, as its maker names it, and what it does with "
        "a torque command",
    )

    @classmethod
    def of(
        cls, plant: PlantSpec, robot: Robot, control_period: float = CONTROL_PERIOD
    ) -> "Assumptions":
        """The assumptions of gains tuned on `plant`, a plant of `robot` (the arm it names)."""
        interface, names = robot.torque_interface, robot.joint_names
        return cls(
            joints=f"{names[0]}..{names[-1]} are {robot.name}'s {len(names)} joints from base "
            "to flange, as its description names them (the joint states' names): the gains are "
            "in that order; map the names if your robot's description names them otherwise",
            gravity_compensation=_gravity_text(plant, interface),
            feedback=(
                "the motor-side joint angle, as the arm's motor encoders report it, and its "
                "velocity as the mean of the last differences of that angle"
                if plant.feedback == "motor"
                else "the link-side joint angle and its velocity"
            ),
            update_rate_hz=round(1 / control_period),
            torque_interface=f"{interface.name}: {interface.description}",
        )


def _gravity_text(plant: PlantSpec, interface: TorqueInterface) -> str:
    """Who adds the arm's gravity torque under u: the robot's torque interface (a plant whose
    interface is fri simulates one that does, whichever the arm), or no one (a plain PD)."""
    if plant.interface == "fri":
        if interface.adds_gravity:
            return (
                f"the robot's own: {interface.name} adds its gravity model, and u is the torque "
                "commanded on top of it"
            )
        return (
            f"the robot's own, as the plant simulated it; {interface.name} adds none: add the "
            "arm's gravity torque to u before commanding it"
        )
    if interface.adds_gravity:
        return (
            f"none: u is the whole motor torque (a plain PD); {interface.name} would add its "
            "gravity compensation to it, and the gains were not tuned so"
        )
    return f"none: u is the whole motor torque (a plain PD), as {interface.name} takes it"


class Controller(BaseModel):
    """One tuned PD controller of an arm (source.model.robot), as `analytic export` writes it:
    a gain pair per joint of the arm, named as its joint states name them."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    format: Literal["gainfarm-controller/1"] = FORMAT
    law: str = LAW
    control_period: float = Field(CONTROL_PERIOD, description="s")
    # The arm's joint names; by default the iiwa 14's, as every file before the arms named them.
    joints: tuple[str, ...] = Field(JOINT_NAMES, min_length=1, max_length=MAX_JOINTS)
    kp: PerJointGains
    kd: PerJointGains
    units: dict[str, str] = UNITS
    member: Member
    source: Source
    limits: Limits | None = Field(
        None,
        description="the safety limits its episodes were checked against and kept to (null: "
        "exported from a run from before the limits, never checked)",
    )
    assumes: Assumptions | None = Field(
        None,
        description="what running the gains on a robot takes for granted (null: exported "
        "before the file said so; the law and source.model tell it)",
    )

    @model_validator(mode="after")
    def _one_gain_per_joint(self) -> Self:
        for name in ("kp", "kd"):
            given = len(getattr(self, name))
            if given != len(self.joints):
                raise ValueError(f"{name}: {given} gains for {len(self.joints)} joints")
        return self

    @property
    def gains(self) -> PDGains:
        return PDGains(kp=self.kp, kd=self.kd)

    @property
    def robot(self) -> str:
        """The arm it was tuned for: its run's plant's robot."""
        return self.source.model.robot


class BadGains(ValueError):
    """A gains file that is not one: the message says where and what, in one line."""


def read_gains(raw: bytes, joints: tuple[str, ...] = JOINT_NAMES) -> list[PDGains]:
    """The candidates in a gains file, JSON or YAML (`analytic export --format yaml` writes the
    same document): a list whose items are {"kp", "kd"} objects or exported controllers, or one
    such object alone, each with a gain per one of `joints` (the robot's; the iiwa 14's by
    default): a controller whose joints are not these, another arm's, is refused. BadGains, in
    plain words, otherwise."""
    if raw.startswith(b"kp1,"):  # the header of front.csv (analytic.records)
        raise BadGains(
            "a run's front.csv, not a controller: `analytic export RUN --member N` writes its "
            "row N as one"
        )
    document = _document(raw)
    if isinstance(document, list):
        if not document:
            raise BadGains("the list of candidates is empty")
        return [
            _candidate(item, f"candidate {n}: ", joints) for n, item in enumerate(document, start=1)
        ]
    return [_candidate(document, "", joints)]


def read_controller(raw: bytes) -> "Controller | None":
    """The exported controller in `raw` (JSON or YAML), or None if it holds another kind of gains
    (read_gains has said whether it holds gains at all)."""
    try:
        document = _document(raw)
    except BadGains:
        return None
    if not (isinstance(document, dict) and "format" in document):
        return None
    try:
        return Controller.model_validate(document)
    except ValidationError:
        return None


_EXPECTED = (
    'expected a controller from `analytic export` or a list of {"kp": [a number per joint], '
    '"kd": [a number per joint]}'
)


def _document(raw: bytes) -> Any:
    """The JSON or YAML document in a gains file: one reader for both, since a controller file is
    either (YAML's safe loader: plain data, never objects). BadGains if it is neither, with the
    reason of the syntax it looks like: JSON if it opens with { or [, else YAML."""
    try:
        text = raw.decode()
    except UnicodeDecodeError:
        raise BadGains("not JSON or YAML text (binary data)") from None
    try:
        return load_json(raw)
    except BadDocument as error:
        raise BadGains(str(error)) from None
    except json.JSONDecodeError as error:
        if text.lstrip().startswith(("{", "[")):
            raise BadGains(
                f"not JSON ({error.msg} at line {error.lineno} column {error.colno}); {_EXPECTED}"
            ) from None
    try:
        document = load_yaml(text)
    except BadDocument as error:
        raise BadGains(str(error)) from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        problem = getattr(error, "problem", None) or "unreadable"
        where = f" at line {mark.line + 1} column {mark.column + 1}" if mark is not None else ""
        raise BadGains(f"not JSON or YAML ({problem}{where}); {_EXPECTED}") from None
    if document is None:
        raise BadGains(f"empty; {_EXPECTED}")
    if not isinstance(document, dict | list):
        raise BadGains(f"a lone value ({str(document)[:40]!r}), not gains; {_EXPECTED}")
    return document


def _candidate(item: Any, where: str, joints: tuple[str, ...]) -> PDGains:
    if not isinstance(item, dict):
        raise BadGains(f'{where}expected an object with "kp" and "kd", got {type(item).__name__}')
    if "format" in item and isinstance(item.get("joints"), list | tuple):
        theirs = tuple(str(joint) for joint in item["joints"])
        if theirs and theirs != tuple(joints):
            raise BadGains(where + _another_arm(item, theirs, joints))
    # The count first, said against the robot's joints: the contract takes any count.
    counts = [
        _count(name, len(value), joints)
        for name in ("kp", "kd")
        if isinstance(value := item.get(name), list | tuple) and len(value) != len(joints)
    ]
    if counts:
        more = len(counts) - 1 + sum(1 for name in ("kp", "kd") if name not in item)
        raise BadGains(where + counts[0] + _more(more))
    try:
        if "format" in item:  # an exported controller: its own checks, then its gains
            return Controller.model_validate(item).gains
        return PDGains.model_validate(item)
    except ValidationError as error:
        raise BadGains(where + problem(error, joints)) from None


def _another_arm(item: dict, theirs: tuple[str, ...], joints: tuple[str, ...]) -> str:
    """A controller of another arm, said in a line: whose it is and whose joints are wanted."""
    source = item.get("source")
    model = source.get("model") if isinstance(source, dict) else None
    robot = model.get("robot") if isinstance(model, dict) else None
    # A name of the robots' form is said as it is; anything else is the file's, quoted.
    named = isinstance(robot, str) and re.fullmatch(ROBOT_PATTERN, robot)
    whose = f"{robot}'s" if named else "another arm's"
    return (
        f"a controller of {whose} {len(theirs)} joints ({quoted(theirs[0])}..{quoted(theirs[-1])}"
        f"), not of this arm's {len(joints)} ({joints[0]}..{joints[-1]})"
    )


def _more(more: int) -> str:
    return f" (and {more} more problem{'s' if more > 1 else ''})" if more else ""


def _count(name: str, given: int, joints: tuple[str, ...]) -> str:
    return f"{name}: {given} gains given, {len(joints)} needed ({joints[0]}..{joints[-1]})"


def problem(error: ValidationError, joints: tuple[str, ...] = JOINT_NAMES) -> str:
    """A gains validation error as a person says it: 'kp of A3: -1.0 is negative (gains are
    at least 0)', 'kd: 3 gains given, 7 needed (A1..A7)'; other fields as `describe` says."""
    errors = error.errors()
    first = errors[0]
    loc, kind, value = first["loc"], first["type"], first.get("input")
    # A gain refused leaves its tuple short too: pydantic's echo, not another problem.
    more = sum(
        1
        for other in errors[1:]
        if not (
            other["type"] == "too_short"
            and any(len(e["loc"]) > 1 and e["loc"][:1] == other["loc"] for e in errors)
        )
    )
    suffix = _more(more)
    if not loc or loc[0] not in ("kp", "kd"):
        if kind == "literal_error" and loc == ("format",):
            return f"format {quoted(value)} is not {FORMAT!r} (a file of another gainfarm version?)"
        if kind == "extra_forbidden" and len(loc) == 1:
            return f"unknown field {quoted(loc[0])}{suffix}"
        return describe(error)
    name = str(loc[0])
    if len(loc) == 1:
        if kind == "missing":
            return f"{name} missing: {len(joints)} gains needed ({joints[0]}..{joints[-1]}){suffix}"
        if kind in ("too_short", "too_long"):
            return _count(name, len(value), joints) + suffix
        return f"{name}: expected a list of {len(joints)} numbers, got {quoted(value)}{suffix}"
    known = isinstance(loc[1], int) and loc[1] < len(joints)
    where = f"{name} of {joints[loc[1]]}" if known else name
    if kind == "greater_than_equal":
        return f"{where}: {quoted(value)} is negative (gains are at least 0){suffix}"
    if kind == "finite_number":
        return f"{where}: {quoted(value)} is not finite{suffix}"
    return f"{where}: {quoted(value)} is not a number{suffix}"
