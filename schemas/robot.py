"""The robot a job runs on: what a robot declares (`Robot`), the iiwa 14's published limits, and
the simulated plant (PlantSpec), which names its robot.

A robot is a plug-in of the group gainfarm.robots (docs/plugins.md): a module's `ROBOT`, of the
`Robot` form below, found by the plant's `robot` name (`gainfarm.models.robot_of`). The iiwa 14,
models/iiwa14.py, is the built-in one and the default. The module-level numbers here (JOINT_NAMES,
N_JOINTS, the limits) are the iiwa 14's, which its ROBOT declares: the code that reads them still
assumes its 7 joints (docs/robot.md lists it).

Every physical number here has a source or is labelled an assumption; models/README.md gives the
sources and the reasons behind each assumption.
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass
from importlib.resources.abc import Traversable
from typing import TYPE_CHECKING, Annotated, Any, Literal, Protocol, Self, runtime_checkable

from pydantic import BaseModel, ConfigDict, Field, model_validator

if TYPE_CHECKING:  # the contract names MuJoCo's types and the gains in hints only
    import mujoco

    from gainfarm.schemas.gains import PDGains

# A robot's name is a name of the gainfarm.robots plug-in group: gainfarm.plugins.NAME_PATTERN's
# form (the contract imports nothing of the project; a test keeps the two equal). The contract
# checks the form only; who runs or tunes on a plant checks the name is installed.
ROBOT_PATTERN = r"^[a-z][a-z0-9_-]{0,31}$"
DEFAULT_ROBOT = "iiwa14"

N_JOINTS = 7
# The most joints a robot may have: a bound for what a file or a message may carry, far above any
# serial arm (the contract checks a per-joint field's length against the robot where it is known).
MAX_JOINTS = 32
JOINT_NAMES = tuple(f"A{i}" for i in range(1, N_JOINTS + 1))

# --- Published limits of the LBR iiwa 14 R820 ----------------------------------------------------

# Torque, N·m (KUKA data sheet); the motors' ctrlrange in models/iiwa14.xml.
TORQUE_LIMITS = (320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)
# Position, rad (KUKA data sheet: ±170, ±120, ±170, ±120, ±170, ±120, ±175°).
POSITION_LIMITS = (2.96706, 2.0944, 2.96706, 2.0944, 2.96706, 2.0944, 3.05433)
# Speed, rad/s (KUKA data sheet: 85, 85, 100, 75, 130, 135, 135 °/s).
SPEED_LIMITS = tuple(math.radians(v) for v in (85.0, 85.0, 100.0, 75.0, 130.0, 135.0, 135.0))
# Acceleration, rad/s² (as published with drake's iiwa model, from a 2019 thesis).
ACCELERATION_LIMITS = (8.57, 8.57, 8.74, 11.36, 12.23, 15.72, 15.72)


# --- What a robot declares (a gainfarm.robots plug-in) -------------------------------------------


@dataclass(frozen=True)
class JointLimits:
    """A robot's published limits, one number per joint, in its joints' order. A joint turns
    ±position, unless `position_range` gives its (lowest, highest) angles (the Panda's fourth
    joint turns from -176° to -4°): then `position` is its largest excursion either way."""

    torque: tuple[float, ...]  # N·m: the motors' saturation
    speed: tuple[float, ...]  # rad/s
    position: tuple[float, ...]  # rad
    acceleration: tuple[float, ...]  # rad/s²
    position_range: tuple[tuple[float, float], ...] | None = None  # rad, where not ±position

    @property
    def ranges(self) -> tuple[tuple[float, float], ...]:
        """Each joint's (lowest, highest) angle, rad."""
        if self.position_range is not None:
            return self.position_range
        return tuple((-limit, limit) for limit in self.position)


@dataclass(frozen=True)
class Workspace:
    """Where a robot works: the posture it starts from and rests in (`home`: the inverse
    kinematics' seed, the fourier kind's centre), and the box of the base frame in which a
    Cartesian trajectory's centre may lie (`low` to `high`, m) with the flange pointing down,
    every point of it reachable; `center` is the default trajectory's centre, inside it."""

    home: tuple[float, ...]  # rad, one per joint
    center: tuple[float, float, float]  # m
    low: tuple[float, float, float]  # m
    high: tuple[float, float, float]  # m

    def __post_init__(self) -> None:
        if not all(a <= c <= b for a, c, b in zip(self.low, self.center, self.high, strict=True)):
            raise ValueError(f"workspace: centre {self.center} outside {self.low}..{self.high}")

    def contains(self, point: tuple[float, float, float]) -> bool:
        """Whether a trajectory may be centred on `point`."""
        return all(a <= c <= b for a, c, b in zip(self.low, point, self.high, strict=True))

    def corners(self) -> tuple[tuple[float, float, float], ...]:
        """The box's 8 corners: with its centre, the points a conformance check reaches."""
        return tuple(
            (x, y, z)
            for x in (self.low[0], self.high[0])
            for y in (self.low[1], self.high[1])
            for z in (self.low[2], self.high[2])
        )


@dataclass(frozen=True)
class TorqueInterface:
    """What the robot's controller does with a torque command, as its maker documents it
    (models/README.md cites each): `adds_gravity`, whether it adds its own gravity model of the
    arm to the command (KUKA's FRI torque mode does: a plant's `interface = "fri"` is this
    behaviour, whichever the arm), `name` the maker's name for the mode."""

    name: str
    adds_gravity: bool
    description: str


STIFFNESS_PRESET_NAMES = ("soft", "medium", "stiff")


@dataclass(frozen=True)
class PlantDefaults:
    """A robot's own numbers for the per-joint plant fields a PlantSpec leaves None (each a source
    or an assumption of the robot's module): its joint springs' presets (`stiffness_presets`,
    keyed by STIFFNESS_PRESET_NAMES) and the one a default plant uses, the springs' damping, the
    rotors' reflected inertia, and the motor-side friction."""

    stiffness_presets: Mapping[str, tuple[float, ...]]  # N·m/rad
    stiffness: str  # the preset of a default plant
    spring_damping: tuple[float, ...]  # N·m·s/rad
    rotor_inertia: tuple[float, ...]  # kg·m², reflected through the gear
    viscous: tuple[float, ...]  # N·m·s/rad
    coulomb: tuple[float, ...]  # N·m


@runtime_checkable
class Robot(Protocol):
    """A robot arm, as a gainfarm.robots plug-in declares it (its module's `ROBOT`): everything
    the worker and the analytic side read of one arm. gainfarm.testing.robots checks one.

    `build` compiles the plant a PlantSpec describes, with rigid or flexible joints as it says
    (cached: a worker runs thousands of episodes on one); `describe` is the same model not yet
    compiled (to export, or to put several arms in one model). The robot's own gravity model,
    what its controller adds to the command under `interface = "fri"`, is the gravity of the
    plant `gravity_spec(spec)` describes: what the robot believes of the arm `spec` is."""

    name: str  # its plug-in name, ROBOT_PATTERN's form
    joint_names: tuple[str, ...]  # the hinges the motors turn, base to flange: the joint count
    limits: JointLimits
    default_gains: "PDGains"  # a sensible first controller, and the search space's centre
    workspace: Workspace
    flange: str  # the MuJoCo site at the flange's centre, which every trajectory moves
    plant_defaults: PlantDefaults  # what a PlantSpec's per-joint fields left None are
    torque_interface: TorqueInterface  # what its controller does with a torque command
    inertial_sets: tuple[str, ...]  # the inertial sets it builds, its default first
    rated_payload: float  # kg, the data sheet's
    uncertainty: Traversable  # its ranges for robust tuning (models/uncertainty.toml's form)

    def build(self, spec: "PlantSpec") -> "mujoco.MjModel": ...

    def describe(self, spec: "PlantSpec") -> "mujoco.MjSpec": ...

    def gravity_spec(self, spec: "PlantSpec") -> "PlantSpec": ...


# --- Elastic joints: assumptions (no authoritative public table exists) --------------------------

# Stiffness presets spanning the plausible range, N·m/rad. "soft" is the first wave's value (and
# the ideal plant's); harmonic-drive catalogues for this torque class give 1e4-1e5.
STIFFNESS_PRESETS: dict[str, tuple[float, ...]] = {
    # The first wave's value (and the ideal plant's); substeps >= 2.
    "soft": (5000.0, 5000.0, 4000.0, 4000.0, 2000.0, 2000.0, 2000.0),
    # As stiff as substeps = 2 (1 ms) integrates well with the CAD inertials (models/README.md);
    # A5-A7 are held there by their links' small inertias, below the catalogue range.
    "medium": (40000.0, 40000.0, 20000.0, 20000.0, 7000.0, 7000.0, 2000.0),
    # The catalogue's upper range, scaled by torque class; substeps >= 7 (cad), >= 5 (open).
    "stiff": (100000.0, 100000.0, 50000.0, 50000.0, 20000.0, 20000.0, 10000.0),
}
DEFAULT_STIFFNESS = STIFFNESS_PRESETS["medium"]  # the stiffest 1 ms physics steps integrate well
DEFAULT_SPRING_DAMPING = (10.0, 10.0, 10.0, 10.0, 5.0, 5.0, 5.0)  # N·m·s/rad
DEFAULT_ROTOR_INERTIA = (0.4, 0.4, 0.3, 0.3, 0.1, 0.1, 0.1)  # kg·m², reflected through the gear

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]


def _per_joint(low: float, high: float, strict: bool = False) -> Any:
    """One finite number per joint (as many as the robot has: `gainfarm.models.resolve` checks
    the count against it) from `low` (excluded if `strict`) to `high`: the bounds of a
    physical quantity, far outside any arm of this class, so that a file's 1e308 is refused
    here, naming its field, rather than overflowing the physics that reads it."""
    bounds = {"gt" if strict else "ge": low, "le": high}
    number = Annotated[float, Field(allow_inf_nan=False, **bounds)]
    return Annotated[tuple[number, ...], Field(min_length=1, max_length=MAX_JOINTS)]


# 100 times the stiffest harmonic drive of the catalogues above (no PlantSpec's substeps can
# integrate more than about 5e5 in any case), and alike far beyond every other number.
Stiffness = _per_joint(0, 1e7, strict=True)
SpringDamping = _per_joint(0, 1e5)
RotorInertia = _per_joint(0, 1e3)
MassScale = _per_joint(0, 100, strict=True)
FrictionTorque = _per_joint(0, 1e4)


class Friction(BaseModel):
    """Motor-side joint friction: τ_f = viscous·θ̇ + coulomb·tanh(θ̇ / smoothing).

    The tanh makes the Coulomb part smooth near zero velocity (as the sigmoidal model of Gaz et
    al., RA-L 2019); `smoothing` also keeps it stable when evaluated once per 2 ms tick.
    None is the robot's own (its PlantDefaults; the iiwa 14's are assumptions, models/README.md:
    Coulomb 1.5 % of each joint's torque limit).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    viscous: FrictionTorque | None = None  # N·m·s/rad
    coulomb: FrictionTorque | None = None  # N·m
    smoothing: float = Field(0.05, gt=0, le=10, allow_inf_nan=False, description="rad/s")


class Sensors(BaseModel):
    """What the robot's sensors report, and how it differs from the simulator's exact state.

    Positions are quantised to `resolution` after adding Gaussian `noise`; velocities are the
    mean of the last `velocity_window` differences of those positions (what real-time clients
    do: KUKA's interface reports no velocity); the joint torque sensor adds `torque_noise`.
    `exact` sensors report the simulator's state as is (the ideal plant). The noise is drawn
    from `seed`, so an episode is reproducible and every candidate meets the same noise.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    exact: bool = False
    resolution: float = Field(
        2 * math.pi / 2**20, ge=0, le=0.01, allow_inf_nan=False, description="rad per count"
    )
    noise: float = Field(2 * math.pi / 2**20, ge=0, le=0.01, allow_inf_nan=False, description="rad")
    velocity_window: int = Field(3, ge=1, le=50, description="ticks of differences averaged")
    torque_noise: float = Field(0.1, ge=0, le=10, allow_inf_nan=False, description="N·m")
    seed: int = Field(0, ge=0, lt=2**63)


# The data sheet's rated payload, kg: the most a load may weigh.
RATED_PAYLOAD = 14.0
# How far from the flange's centre a load's centre of mass may be, m (assumption: a tool as
# long as a forearm, beyond which a told centre is more likely a typo in mm than a tool).
MAX_LOAD_OFFSET = 0.5


class LoadData(BaseModel):
    """The load data the robot is told (KUKA's load data: mass and centre of mass, in the flange
    frame), which its own gravity model carries (FRI gravity compensation), and how far the load
    really held is off it (`mass_scale`), which the robot's model does not know.

    The plant holds a solid sphere of `mass` × `mass_scale` centred on `com`; the robot's model
    the same sphere of `mass` (gravity reads only a body's mass and centre).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    mass: float = Field(
        gt=0, le=RATED_PAYLOAD, allow_inf_nan=False, description="kg, as the robot is told"
    )
    com: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0),
        description="m, in the flange frame (z along the flange's axis, away from the arm): "
        "the centre of mass as the robot is told; by default the flange's centre",
    )
    mass_scale: float = Field(
        1.0,
        gt=0,
        le=5,
        allow_inf_nan=False,
        # Not bound by the rated payload: a load heavier than told is what a variant tests.
        description="the load's true mass against the told one (a variant's error of the load "
        "data); the robot's gravity model does not know it",
    )

    @model_validator(mode="after")
    def _sensible(self) -> Self:
        if not all(math.isfinite(v) and abs(v) <= MAX_LOAD_OFFSET for v in self.com):
            raise ValueError(f"com: finite, each within {MAX_LOAD_OFFSET:g} m of the flange")
        return self

    @property
    def told(self) -> "LoadData":
        """The load as the robot knows it: its true mass is the told one."""
        return self if self.mass_scale == 1.0 else self.model_copy(update={"mass_scale": 1.0})


class PlantSpec(BaseModel):
    """Which simulated robot runs an episode. Values are explicit so that logs record them.

    The default is the most realistic plant the published numbers support, behind the robot's
    own torque interface (KUKA's FRI torque mode adds gravity compensation from the robot's model
    of the arm); `IDEAL_PLANT` is the first wave's idealised one (exact sensors, no friction, no
    delay, link-side feedback, the command is the motor torque: the paper's plain PD).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    robot: str = Field(
        DEFAULT_ROBOT,
        pattern=ROBOT_PATTERN,
        description="the arm: a gainfarm.robots plug-in's name, installed where the plant runs "
        "(iiwa14, the built-in one); its limits, gains, gravity model and workspace are its own",
    )
    joints: Literal["flexible", "rigid"] = "flexible"
    inertials: str = Field(
        "menagerie",
        pattern=ROBOT_PATTERN,
        description="the links' masses and inertias, one of the robot's sets (models/README.md): "
        "every shipped arm has MuJoCo Menagerie's; the iiwa 14 also the open descriptions' "
        "older axes (open) and KUKA's CAD masses (cad). The robot's own gravity model "
        "(interface fri) is this set",
    )
    # Per joint, one number each; None is the robot's own (its PlantDefaults), and a stiffness
    # may name one of the robot's presets. `gainfarm.models.resolve` writes them out, checked
    # against the robot's joints: the worker logs the plant it ran, so a log's numbers are
    # explicit.
    stiffness: Stiffness | Literal["soft", "medium", "stiff"] | None = None
    spring_damping: SpringDamping | None = None
    rotor_inertia: RotorInertia | None = None
    friction: Friction | None = Friction()
    delay: int = Field(1, ge=0, le=50, description="ticks before a command acts")
    sensors: Sensors = Sensors()
    feedback: Literal["link", "motor"] = Field(
        "motor", description="the side whose measured angle the PD feeds back"
    )
    substeps: int = Field(2, ge=1, le=50, description="physics steps per 2 ms control tick")
    mass_scale: MassScale | None = Field(
        None,
        description="each link's true mass (and its inertia alike) against the named set's, "
        "one per joint's link, base to flange (None: 1 each); the robot's gravity model does not "
        "know it",
    )
    payload: float = Field(
        0.0,
        ge=0,
        le=RATED_PAYLOAD,
        allow_inf_nan=False,
        description="kg held at the flange's centre (the data sheet's rated payload is 14 kg) "
        "that the robot was not told of: its gravity model does not know it (a told load is "
        "`load`)",
    )
    load: LoadData | None = Field(
        None,
        # Left out of the JSON when no load is told: every spec from before it keeps its bytes
        # (a log's metadata, a run's config, the wire).
        exclude_if=lambda load: load is None,
        description="the load data the robot is told, which both the plant and the robot's "
        "gravity model carry (the plant off by the load's `mass_scale`); None: told of none",
    )
    interface: Literal["fri", "torque"] = Field(
        "fri",
        description="fri: KUKA's FRI torque mode, the robot adds gravity compensation from its "
        "own model of the arm (`inertials`) at the measured joint angles, and the command is "
        "the torque on top; torque: the command is the motor torque (the paper's plain PD)",
    )

    @model_validator(mode="before")
    @classmethod
    def _written_before_the_interface(cls, data: Any) -> Any:
        # A spec written before `interface` existed (a log's metadata, a run's config) names
        # every other field, as a dump does: its episodes commanded the motor torque.
        if isinstance(data, dict) and "interface" not in data and data.keys() >= _EARLIER_FIELDS:
            return {**data, "interface": "torque"}
        return data

    @model_validator(mode="after")
    def _rotors_have_inertia(self) -> Self:
        # An elastic joint's motor side is its rotor alone: without inertia the mass matrix is
        # singular and the simulation meaningless.
        rotors = self.rotor_inertia
        if self.joints == "flexible" and rotors is not None and min(rotors) <= 0:
            raise ValueError("rotor_inertia must be positive on every joint of flexible joints")
        return self

    @property
    def ideal(self) -> bool:
        """Whether the sensors, actuators and joints are the first wave's idealised ones."""
        return (
            self.friction is None
            and self.delay == 0
            and self.sensors.exact
            and self.feedback == "link"
        )


# What every dump of a PlantSpec held before the torque interface was a choice.
_EARLIER_FIELDS = frozenset(PlantSpec.model_fields) - {"interface", "payload", "mass_scale", "load"}

IDEAL_PLANT = PlantSpec(
    inertials="open",
    stiffness="soft",
    friction=None,
    delay=0,
    sensors=Sensors(exact=True),
    feedback="link",
    interface="torque",
)
REALISTIC_PLANT = PlantSpec()
# The realistic plant without the robot's gravity compensation: the paper's plain PD on it.
PLAIN_PLANT = PlantSpec(interface="torque")
PLANTS = {"realistic": REALISTIC_PLANT, "plain": PLAIN_PLANT, "ideal": IDEAL_PLANT}
