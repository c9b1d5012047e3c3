"""The one lookup from a plant to its robot: every use of an arm's facts goes through here.

A plant (PlantSpec) names its robot (`spec.robot`); the robot is the gainfarm.robots plug-in of
that name (gainfarm.plugins): the built-in iiwa 14 (models/iiwa14.py's ROBOT) or a third party's,
installed by an entry point. `compile_model` and `build_spec` are the named robot's, so the
worker, the referee and the analytic side build whichever arm the plant names.
"""

from functools import lru_cache

import mujoco

from gainfarm import plugins
from gainfarm.models import elastic
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.robot import DEFAULT_ROBOT, PLANTS, Friction, PlantSpec, Robot


class PlantError(ValueError):
    """A plant its robot cannot be: a per-joint field of another joint count, an inertial set
    or a stiffness preset it lacks, a payload beyond its rating. Said in one line naming the
    field."""


def robot_of(spec: PlantSpec | str = DEFAULT_ROBOT) -> Robot:
    """The robot plant `spec` names (or the one named so). PluginError, in one line naming what
    the group has, if this installation has none of that name or it is not a Robot."""
    name = spec if isinstance(spec, str) else spec.robot
    robot = plugins.load(plugins.ROBOTS, name)
    if id(robot) in _conforming:
        return robot
    if not isinstance(robot, Robot):  # checks the members are there; the kit checks the rest
        raise plugins.PluginError(
            f"{plugins.ROBOTS}: {name!r} is a {type(robot).__name__}, not a robot (it lacks "
            f"{', '.join(_missing(robot))}; docs/plugins.md)"
        )
    _conforming[id(robot)] = robot  # held, so that its id is never another object's
    return robot


# The robots found of the Robot form, by id: a protocol's isinstance costs some 150 µs, and a
# worker looks its robot up several times per episode.
_conforming: dict[int, Robot] = {}


@lru_cache(maxsize=256)
def resolve(spec: PlantSpec) -> PlantSpec:
    """`spec` with every per-joint number written out: those it leaves None are its robot's own
    (the robot's PlantDefaults), a stiffness preset's name the robot's preset; each checked to
    have one number per joint of the robot, the inertial set to be one the robot has and the
    payloads within its rating. PlantError (one line, naming the field) if not. Idempotent."""
    robot = robot_of(spec)
    defaults, joints = robot.plant_defaults, len(robot.joint_names)
    stiffness = defaults.stiffness if spec.stiffness is None else spec.stiffness
    if isinstance(stiffness, str):
        if stiffness not in defaults.stiffness_presets:
            raise PlantError(f"stiffness: {robot.name} has no preset {stiffness!r}")
        stiffness = defaults.stiffness_presets[stiffness]
    friction = spec.friction
    if friction is not None:
        friction = Friction(
            viscous=defaults.viscous if friction.viscous is None else friction.viscous,
            coulomb=defaults.coulomb if friction.coulomb is None else friction.coulomb,
            smoothing=friction.smoothing,
        )
    numbers = {
        "stiffness": stiffness,
        "spring_damping": _given(spec.spring_damping, defaults.spring_damping),
        "rotor_inertia": _given(spec.rotor_inertia, defaults.rotor_inertia),
        "mass_scale": _given(spec.mass_scale, (1.0,) * joints),
    }
    if friction is not None:
        numbers |= {"friction.viscous": friction.viscous, "friction.coulomb": friction.coulomb}
    for field, values in numbers.items():
        if len(values) != joints:
            raise PlantError(
                f"{field}: {len(values)} numbers for {robot.name}'s {joints} joints "
                f"({', '.join(robot.joint_names)})"
            )
    if spec.inertials not in robot.inertial_sets:
        raise PlantError(
            f"inertials: {robot.name} has no set {spec.inertials!r} "
            f"(it has {', '.join(robot.inertial_sets)})"
        )
    told = 0.0 if spec.load is None else spec.load.mass
    if spec.payload > robot.rated_payload or told > robot.rated_payload:
        raise PlantError(
            f"payload: {max(spec.payload, told):g} kg is beyond {robot.name}'s rated "
            f"{robot.rated_payload:g} kg"
        )
    written = {
        field: values for field, values in numbers.items() if not field.startswith("friction.")
    }
    resolved = spec.model_copy(update={**written, "friction": friction})
    # Validated again: a robot's own numbers meet the contract's bounds like a file's.
    return PlantSpec.model_validate(resolved.model_dump())


def written_out(spec: EpisodeSpec) -> EpisodeSpec:
    """The episode `spec` with its plant written out (`resolve`): what its worker runs and logs,
    which is what a log is checked against."""
    plant = resolve(spec.plant)
    return spec if plant == spec.plant else spec.model_copy(update={"plant": plant})


def _given(values: tuple[float, ...] | None, default: tuple[float, ...]) -> tuple[float, ...]:
    return default if values is None else values


def plant_preset(name: str, robot: str = DEFAULT_ROBOT) -> PlantSpec:
    """The plant preset `name` (schemas.robot.PLANTS: realistic, plain, ideal) of `robot`. The
    ideal plant's inertials are the first wave's (the iiwa 14's open set) where the robot has
    them, else its default set."""
    spec = PLANTS[name].model_copy(update={"robot": robot})
    sets = robot_of(robot).inertial_sets
    return spec if spec.inertials in sets else spec.model_copy(update={"inertials": sets[0]})


def min_substeps(spec: PlantSpec) -> int:
    """The fewest physics steps per 2 ms tick that integrate the joint springs of `spec`'s arm
    well (models/elastic.py); 1 for rigid joints. The robot's own `min_substeps` where it has one
    (the built-in arms), else from its flexible model at home and at zero, by the flexible
    model's hinge names (`J_motor`, `J_spring`), which the worker reads too."""
    robot = robot_of(spec)
    own = getattr(robot, "min_substeps", None)
    if own is not None:
        return own(spec)
    spec = resolve(spec)
    if spec.joints != "flexible":
        return 1
    model = robot.describe(spec).compile()  # not `build`: that refuses too few substeps
    postures = (robot.workspace.home, (0.0,) * len(robot.joint_names))
    inertia = elastic.effective_inertias(model, robot.joint_names, postures)
    return elastic.min_substeps(spec.stiffness, spec.spring_damping, inertia, robot.joint_names)


def compile_model(spec: PlantSpec) -> mujoco.MjModel:
    """The compiled plant `spec` describes, built by its robot (cached by the robot)."""
    return robot_of(spec).build(spec)


def build_spec(spec: PlantSpec) -> mujoco.MjSpec:
    """The plant `spec` describes as its robot writes it, not yet compiled."""
    return robot_of(spec).describe(spec)


def _missing(thing: object) -> list[str]:
    members = (*Robot.__annotations__, "build", "describe", "gravity_spec")
    return [member for member in members if not hasattr(thing, member)]
