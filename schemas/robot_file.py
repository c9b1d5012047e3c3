"""A user's own arm as a file: the robot description `--robot my_arm.toml` reads.

The model file (an MJCF or a URDF, named relative to the description) gives the arm's bodies,
inertials and hinges; the description gives what model files do not carry reliably: the joints
the motors turn (base to flange), the flange, the data sheet's limits, default gains, the maker's
torque interface, the workspace, the rated payload, the elastic-joint and friction numbers (or a
stated rule) and, optionally, the ranges robust tuning draws from. docs/robot.md, "Your own arm",
has a complete example (docs/examples/my_arm.toml).

Here the file's form is checked, each problem in one line naming its field: a missing field, a
per-joint list of another length than `joints`, a limit not positive, home beyond the position
limits, the workspace's centre outside its box. What needs the model (its joints, the flange, the
reach of the workspace) models/described.py checks when it builds the arm.
"""

import math
import tomllib
from typing import Annotated, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from gainfarm.schemas.documents import BadDocument, load_toml
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import MAX_JOINTS, ROBOT_PATTERN, STIFFNESS_PRESET_NAMES
from gainfarm.schemas.wire import describe

MAX_FILE_BYTES = 1 << 16  # a description is a few kB
MODEL_SUFFIXES = (".xml", ".urdf")
# The rule that fills in the plant numbers a description leaves out (models/described.py).
TORQUE_SCALED = "torque-scaled"
# models/elastic.py names the two hinges of a flexible joint J `J_motor` and `J_spring`: a joint
# of the model named so would be mistaken for one of them.
RESERVED_SUFFIXES = ("_motor", "_spring")


def _numbers(low: float, high: float, strict: bool = True) -> object:
    """One finite number per joint from `low` (excluded if `strict`) to `high`: a physical
    bound far beyond any arm, so that a unit slip (mN·m, degrees) is refused here."""
    bounds = {"gt" if strict else "ge": low, "le": high}
    number = Annotated[float, Field(allow_inf_nan=False, **bounds)]
    return Annotated[tuple[number, ...], Field(min_length=1, max_length=MAX_JOINTS)]


Torques = _numbers(0, 1e5)  # N·m
Speeds = _numbers(0, 100)  # rad/s
Positions = _numbers(0, 10)  # rad, each joint turning ±position (10: 170 would be degrees)
Accelerations = _numbers(0, 1e4)  # rad/s²
Stiffnesses = _numbers(0, 1e7)  # N·m/rad: schemas.robot's Stiffness bound
Dampings = _numbers(0, 1e5, strict=False)  # N·m·s/rad
Inertias = _numbers(0, 1e3)  # kg·m²: a rotor must turn some (flexible joints)
Frictions = _numbers(0, 1e4, strict=False)
Angle = Annotated[float, Field(allow_inf_nan=False, ge=-10, le=10)]  # rad, as Positions
PositionRanges = Annotated[
    tuple[tuple[Angle, Angle], ...], Field(min_length=1, max_length=MAX_JOINTS)
]
Angles = Annotated[
    tuple[Annotated[float, Field(allow_inf_nan=False)], ...],
    Field(min_length=1, max_length=MAX_JOINTS),
]
Point = tuple[
    Annotated[float, Field(allow_inf_nan=False, ge=-100, le=100)],
    Annotated[float, Field(allow_inf_nan=False, ge=-100, le=100)],
    Annotated[float, Field(allow_inf_nan=False, ge=-100, le=100)],
]  # m
Name = Annotated[str, Field(min_length=1, max_length=100)]
# A joint's name as an episode log carries it (its JointState messages name the joints): a ROS
# name's characters, as schemas/episode.py's JointName allows.
JointName = Annotated[str, Field(pattern=r"^[A-Za-z][A-Za-z0-9_/]{0,63}$")]
Text = Annotated[str, Field(min_length=1, max_length=2000)]


class _Table(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class FlangeTable(_Table):
    """The flange: a site of the model, or a body of it with the flange's offset in its frame
    (`pos`, m; `quat`, w x y z), z out of the flange, away from the arm."""

    site: Name | None = None
    body: Name | None = None
    pos: Point = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    def check(self) -> None:
        """ValueError naming the field if the flange is not exactly one of a site or a body."""
        if (self.site is None) == (self.body is None):
            raise ValueError("flange: give a site, or a body (with pos and quat)")
        offset = self.pos != (0.0, 0.0, 0.0) or self.quat != (1.0, 0.0, 0.0, 0.0)
        if self.site is not None and offset:
            raise ValueError("flange: pos and quat go with a body, not with a site")
        norm = math.sqrt(sum(v * v for v in self.quat))
        if not (math.isfinite(norm) and norm > 1e-6):
            raise ValueError("flange.quat: a rotation (w x y z) of non-zero length")


class LimitsTable(_Table):
    """The data sheet's limits, one per joint: model files carry none of them reliably. A
    joint's angles are ±position, or, for an arm whose joints are not symmetric (the Panda's
    fourth), position_range's (lowest, highest): one of the two."""

    torque: Torques  # type: ignore[valid-type]
    speed: Speeds  # type: ignore[valid-type]
    position: Positions | None = None  # type: ignore[valid-type]
    position_range: PositionRanges | None = None
    acceleration: Accelerations  # type: ignore[valid-type]

    def check(self) -> None:
        """ValueError naming the field unless the angles are given one way, each range rising."""
        if (self.position is None) == (self.position_range is None):
            raise ValueError("limits.position: give it, or limits.position_range (not both)")
        for i, (lowest, highest) in enumerate(self.position_range or ()):
            if not lowest < highest:
                raise ValueError(
                    f"limits.position_range.{i}: lowest {lowest:g} rad is not below highest "
                    f"{highest:g} rad"
                )

    def ranges(self) -> tuple[tuple[float, float], ...]:
        """Each joint's (lowest, highest) angle, rad."""
        if self.position_range is not None:
            return self.position_range
        return tuple((-limit, limit) for limit in self.position or ())

    def excursion(self) -> tuple[float, ...]:
        """Each joint's largest angle either way, rad (schemas.robot.JointLimits.position)."""
        return tuple(max(-lowest, highest) for lowest, highest in self.ranges())


class InterfaceTable(_Table):
    """What the robot's controller does with a torque command (schemas.robot.TorqueInterface)."""

    name: Name
    adds_gravity: bool
    description: Text


class WorkspaceTable(_Table):
    """schemas.robot.Workspace: home (rad, per joint), the default centre and the box of
    centres (m, base frame), the flange pointing down."""

    home: Angles
    center: Point
    low: Point
    high: Point


class StiffnessPresets(_Table):
    soft: Stiffnesses  # type: ignore[valid-type]
    medium: Stiffnesses  # type: ignore[valid-type]
    stiff: Stiffnesses  # type: ignore[valid-type]


class PlantTable(_Table):
    """The elastic joints and friction (schemas.robot.PlantDefaults): each given, or, with
    `rule = "torque-scaled"`, those left out scaled from the iiwa 14's by torque limit
    (models/described.py). `source` says where the numbers come from, or that they are
    assumptions."""

    source: Text
    rule: Literal["torque-scaled"] | None = None
    stiffness: Literal["soft", "medium", "stiff"] = "medium"
    stiffness_presets: StiffnessPresets | None = None
    spring_damping: Dampings | None = None  # type: ignore[valid-type]
    rotor_inertia: Inertias | None = None  # type: ignore[valid-type]
    viscous: Frictions | None = None  # type: ignore[valid-type]
    coulomb: Frictions | None = None  # type: ignore[valid-type]

    def check(self) -> None:
        """ValueError naming the field if a number is missing with no rule to fill it in, or a
        rule's numbers are not labelled assumptions (as every physical number of the project's
        carries a source or says it is one)."""
        if self.rule is not None and "assumption" not in self.source.lower():
            raise ValueError(
                f"plant.source: the {self.rule} rule's numbers are assumptions: say so "
                "(e.g. 'assumption: the iiwa 14's, scaled by torque limit')"
            )
        if self.rule is None:
            for field in ("stiffness_presets", *PLANT_LISTS):
                if getattr(self, field) is None:
                    raise ValueError(
                        f"plant.{field}: missing (give it, or rule = {TORQUE_SCALED!r} to scale "
                        "it from the iiwa 14's)"
                    )

    def per_joint(self) -> dict[str, tuple[float, ...]]:
        """Every per-joint list given, by its field's dotted name."""
        lists = {f"plant.{f}": getattr(self, f) for f in PLANT_LISTS}
        if self.stiffness_presets is not None:
            for preset in STIFFNESS_PRESET_NAMES:
                lists[f"plant.stiffness_presets.{preset}"] = getattr(self.stiffness_presets, preset)
        return {field: values for field, values in lists.items() if values is not None}


PLANT_LISTS = ("spring_damping", "rotor_inertia", "viscous", "coulomb")


class RobotFile(_Table):
    """What a robot description holds (docs/robot.md, "Your own arm")."""

    name: str = Field(pattern=ROBOT_PATTERN, description="the robot's plug-in name")
    model: Name = Field(description="an MJCF (.xml) or URDF (.urdf), relative to this file")
    joints: tuple[JointName, ...] = Field(
        min_length=1, max_length=MAX_JOINTS, description="the hinges, base to flange"
    )
    flange: FlangeTable
    limits: LimitsTable
    default_gains: PDGains
    torque_interface: InterfaceTable
    workspace: WorkspaceTable
    rated_payload: float = Field(gt=0, le=1000, allow_inf_nan=False, description="kg")
    plant: PlantTable
    uncertainty: Name | None = Field(
        None, description="a ranges file (models/uncertainty.toml's form), relative to this file"
    )

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        if not self.model.lower().endswith(MODEL_SUFFIXES):
            raise ValueError(f"model: {self.model!r} is neither an MJCF (.xml) nor a URDF (.urdf)")
        self._check_joint_names()
        self.flange.check()
        self.limits.check()
        self.plant.check()
        count = len(self.joints)
        for field, values in self._per_joint().items():
            if len(values) != count:
                raise ValueError(
                    f"{field}: {len(values)} numbers for the {count} joints "
                    f"({', '.join(self.joints)})"
                )
        self._check_workspace()
        return self

    def _check_joint_names(self) -> None:
        if len(set(self.joints)) != len(self.joints):
            raise ValueError("joints: a joint named twice")
        for joint in self.joints:
            if joint.endswith(RESERVED_SUFFIXES):
                raise ValueError(
                    f"joints: {joint!r} ends in {' or '.join(RESERVED_SUFFIXES)}, the names of a "
                    "flexible joint's two hinges: rename it in the model"
                )

    def _per_joint(self) -> dict[str, tuple[float, ...]]:
        limits = {
            f"limits.{f}": getattr(self.limits, f)
            for f in LimitsTable.model_fields
            if getattr(self.limits, f) is not None
        }
        gains = {f"default_gains.{f}": getattr(self.default_gains, f) for f in ("kp", "kd")}
        return {**limits, **gains, "workspace.home": self.workspace.home, **self.plant.per_joint()}

    def _check_workspace(self) -> None:
        space = self.workspace
        ranges = self.limits.ranges()
        for joint, angle, (lowest, highest) in zip(self.joints, space.home, ranges, strict=True):
            if not lowest <= angle <= highest:
                limit = f"±{highest:g}" if lowest == -highest else f"{lowest:g} to {highest:g}"
                raise ValueError(
                    f"workspace.home: {joint} at {angle:g} rad is beyond its position limit "
                    f"{limit} rad"
                )
        if not all(a <= b for a, b in zip(space.low, space.high, strict=True)):
            raise ValueError(f"workspace.low: {space.low} is not below high {space.high}")
        if not all(
            a <= c <= b for a, c, b in zip(space.low, space.center, space.high, strict=True)
        ):
            raise ValueError(
                f"workspace.center: {space.center} lies outside the box {space.low}..{space.high}"
            )


class BadRobotFile(ValueError):
    """Not a robot description, or not one of an arm that can be built: one line naming the
    field."""


def read_robot_file(raw: bytes) -> RobotFile:
    """The robot description in `raw` (TOML), or BadRobotFile in one line naming the field."""
    if len(raw) > MAX_FILE_BYTES:
        raise BadRobotFile(f"{len(raw)} bytes, more than a robot description's {MAX_FILE_BYTES}")
    try:
        table = load_toml(raw.decode())
    except UnicodeDecodeError:
        raise BadRobotFile("not text") from None
    except tomllib.TOMLDecodeError as error:
        raise BadRobotFile(f"not TOML: {error}") from None
    except BadDocument as error:
        raise BadRobotFile(str(error)) from None
    try:
        return RobotFile.model_validate(table)
    except ValidationError as error:
        raise BadRobotFile(describe(error, known=RobotFile.model_fields)) from None
