"""The one lookup from a plant to its robot: every use of an arm's facts goes through here.

A plant (PlantSpec) names its robot (`spec.robot`); the robot is the gainfarm.robots plug-in of
that name (gainfarm.plugins): the built-in iiwa 14 (models/iiwa14.py's ROBOT) or a third party's,
installed by an entry point. `compile_model` and `build_spec` are the named robot's, so the
worker, the referee and the analytic side build whichever arm the plant names.
"""

import mujoco

from gainfarm import plugins
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec, Robot


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


def compile_model(spec: PlantSpec) -> mujoco.MjModel:
    """The compiled plant `spec` describes, built by its robot (cached by the robot)."""
    return robot_of(spec).build(spec)


def build_spec(spec: PlantSpec) -> mujoco.MjSpec:
    """The plant `spec` describes as its robot writes it, not yet compiled."""
    return robot_of(spec).describe(spec)


def _missing(thing: object) -> list[str]:
    members = (*Robot.__annotations__, "build", "describe", "gravity_spec")
    return [member for member in members if not hasattr(thing, member)]
