"""A user's own arm from a robot description file (schemas/robot_file.py; docs/robot.md, "Your own
arm"), built by models/mjcf_arm.py as the shipped arms are.

`robot_from_file` reads the description and its model file, MJCF or URDF (MuJoCo compiles both:
`MjSpec.from_file`), checks what needs the model, and returns the arm; `register_file` registers it
in this process under the name it gives (gainfarm.plugins), `source_of` tells which file a name
came from, so that a process starting workers can hand them `--robot FILE`.

What of the model is kept: the bodies, their inertials, the named hinges and the collision geoms
(a URDF's visuals MuJoCo drops, as it does by default, and its fixed joints it fuses), written
out by MuJoCo with 6 significant digits (at most 5 µm in a metre, 5 mg in a kilogram). The
model's actuators, sensors, tendons, equality constraints, contact pairs, keyframes and bodies'
gravity compensation (gravcomp) go (the arm is driven by torque motors models/mjcf_arm.py adds,
is held up by the robot's gravity model only, and touches nothing), and so do its other joints
(a gripper's fingers, a free base), the bodies they moved welded where they stand. A URDF's
<limit> becomes the hinge's range and actuator force range, and its velocity is not read: the
description's limits are the arm's.

Checks, each refused in one line naming the field (BadRobotFile): the file's form
(schemas/robot_file.py); here, the model file readable and compiling, the joints there, hinges,
base to flange; the flange moved by the last joint; the plant the description gives built, rigid
and flexible (its springs integrable at the default physics step); and the workspace within the
arm's reach with the flange pointing down, at its centre and every corner: a bound from the
links' lengths, which needs no inverse kinematics (the models layer may not import the worker).
The worker's inverse kinematics solves every episode's path and refuses an unreachable one; the
robot kit (gainfarm.testing.robots.check_workspace) solves the centre and corners with it.
"""

import io
import math
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from importlib.resources import files
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import tomli_w

from gainfarm import plugins
from gainfarm.models.iiwa14 import VISCOUS_FRICTION
from gainfarm.models.mjcf_arm import MjcfArm
from gainfarm.models.robots import PlantError, resolve
from gainfarm.schemas.documents import BadDocument, load_toml, read_bounded
from gainfarm.schemas.robot import (
    DEFAULT_ROTOR_INERTIA,
    DEFAULT_SPRING_DAMPING,
    RATED_PAYLOAD,
    STIFFNESS_PRESET_NAMES,
    STIFFNESS_PRESETS,
    TORQUE_LIMITS,
    JointLimits,
    PlantDefaults,
    PlantSpec,
    TorqueInterface,
    Workspace,
)
from gainfarm.schemas.robot_file import MAX_FILE_BYTES, BadRobotFile, RobotFile, read_robot_file

FLANGE = "flange"  # the site a flange given as a body becomes
# The iiwa 14's rule for Coulomb friction (models/iiwa14.py): 1.5 % of each joint's torque limit.
COULOMB_SHARE = 0.015
# The iiwa 14's untold payload range is up to 3 kg of its rated 14 (models/uncertainty.toml).
IIWA_PAYLOAD_RANGE = 3.0
# Rounding a reach's bound is not a reason to refuse: 1 mm.
REACH_SLACK = 1e-3  # m
MAX_MODEL_BYTES = 64 << 20  # an arm's MJCF or URDF, meshes apart, is far smaller

_sources: dict[str, Path] = {}  # name -> the description file it was registered from


class Text(Traversable):
    """A file held in memory, read as importlib.resources' files are: the model as prepared
    here, a generated ranges file (MjcfArm and Robot.uncertainty take a Traversable)."""

    def __init__(self, name: str, text: str):
        self._name, self._text = name, text

    @property
    def name(self) -> str:
        return self._name

    def read_text(self, encoding: str | None = None) -> str:
        return self._text

    def read_bytes(self) -> bytes:
        return self._text.encode()

    def open(self, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        return io.BytesIO(self.read_bytes()) if "b" in mode else io.StringIO(self._text)

    def is_file(self) -> bool:
        return True

    def is_dir(self) -> bool:
        return False

    def iterdir(self) -> Iterator[Traversable]:
        return iter(())

    def joinpath(self, *descendants: str) -> Traversable:
        raise FileNotFoundError(f"{self._name} is a file, not a directory")

    def __repr__(self) -> str:
        return f"<text {self._name}>"


# --- the description ------------------------------------------------------------------------------


def robot_from_file(path: Path) -> MjcfArm:
    """The arm `path` describes, checked (the module's docstring lists how); BadRobotFile in one
    line naming the field if it cannot be built as described. Not registered: a plant finds its
    robot by name, so `register_file` it to run on it."""
    path = Path(path)
    described = _read(path)
    _check_name(described.name, path)
    arm = MjcfArm(
        name=described.name,
        mjcf=_prepared(_beside(path, described.model, "model"), described),
        joint_names=described.joints,
        limits=_limits(described),
        default_gains=described.default_gains,
        workspace=Workspace(**described.workspace.model_dump()),
        torque_interface=TorqueInterface(**described.torque_interface.model_dump()),
        plant_defaults=plant_defaults(described),
        rated_payload=described.rated_payload,
        uncertainty=_uncertainty(path, described),
        flange=described.flange.site or FLANGE,
    )
    with _held(arm):
        _check_plant(arm, described)
        _check_reach(arm)
    return arm


def _limits(described: RobotFile) -> JointLimits:
    limits = described.limits
    return JointLimits(
        torque=limits.torque,
        speed=limits.speed,
        position=limits.excursion(),
        acceleration=limits.acceleration,
        position_range=limits.position_range,
    )


def register_file(path: Path) -> str:
    """Register the arm `path` describes in this process (gainfarm.plugins) and return its
    name. BadRobotFile in one line if it cannot be built or its name is another robot's."""
    arm = robot_from_file(path)
    _replace(arm.name, arm)
    _sources[arm.name] = Path(path).resolve()
    return arm.name


def source_of(name: str) -> Path | None:
    """The description file the robot `name` was registered from here, None if none was."""
    return _sources.get(name)


def forget(name: str) -> None:
    """Unregister the robot `register_file` registered as `name` (nothing if it did not)."""
    if _sources.pop(name, None) is not None:
        plugins.unregister(plugins.ROBOTS, name)
        resolve.cache_clear()


def _read(path: Path) -> RobotFile:
    try:
        raw = read_bounded(path, MAX_FILE_BYTES)
    except BadDocument as error:
        raise BadRobotFile(str(error)) from None
    except OSError as error:
        raise BadRobotFile(f"cannot read it: {error.strerror or error}") from None
    return read_robot_file(raw)


def _check_name(name: str, path: Path) -> None:
    """Refuse a name another robot has here: a built-in, an installed one, or one registered from
    another description (the same file again replaces its own)."""
    if name in _sources and _sources[name] != path.resolve():
        raise BadRobotFile(f"name: {name!r} is the robot described in {_sources[name]}")
    if name in plugins.names(plugins.ROBOTS) and name not in _sources:
        raise BadRobotFile(f"name: {name!r} is a robot installed here; choose another")


def _beside(description: Path, name: str, field: str) -> Path:
    """The file `name`, relative to the description's folder; BadRobotFile if there is none."""
    path = description.parent / name
    if not path.is_file():
        raise BadRobotFile(f"{field}: no file {str(path)!r}")
    return path


# --- the model ------------------------------------------------------------------------------------


def _prepared(path: Path, described: RobotFile) -> Text:
    """The model file as the MJCF MjcfArm builds from: checked against the description, what it
    does not use removed, the flange site added, its meshes' folders made absolute."""
    try:
        size = path.stat().st_size
        if size > MAX_MODEL_BYTES:
            raise BadRobotFile(f"model: {size} bytes, more than an arm's {MAX_MODEL_BYTES}")
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as error:  # MuJoCo's parser: its first line says where
        raise BadRobotFile(f"model: {_first_line(error)}") from None
    hinges = _hinges(spec, described.joints)
    for hinge in hinges:
        # A URDF's <limit effort> becomes the hinge's actuator force range: the description's
        # torque limit is the arm's (its motors' ctrlrange), not clipped again by the file's.
        hinge.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
    _weld_others(spec, set(described.joints))
    for part in [*spec.actuators, *spec.sensors, *spec.tendons, *spec.equalities, *spec.keys]:
        spec.delete(part)
    for part in spec.pairs:
        spec.delete(part)
    for body in spec.bodies:
        # MuJoCo's own gravity compensation of a body (Menagerie sets it on some arms) would hold
        # the arm for nothing: the plant's gravity is compensated only by the robot's model, as
        # its torque interface says.
        body.gravcomp = 0.0
    _place_flange(spec, described, hinges[-1].parent)
    folder = Path(spec.modelfiledir or path.parent).resolve()
    spec.meshdir = str(folder / spec.meshdir)
    spec.texturedir = str(folder / spec.texturedir)
    try:
        text = spec.to_xml()  # compiles: a model MuJoCo cannot build is refused here
    except ValueError as error:
        raise BadRobotFile(f"model: {_first_line(error)}") from None
    return Text(path.name, text)


def _hinges(spec: mujoco.MjSpec, joints: tuple[str, ...]) -> list[mujoco.MjsJoint]:
    """The described joints in the model: each there, a hinge, each beyond the one before."""
    found = {joint.name: joint for joint in spec.joints}
    hinges = []
    for name in joints:
        if name not in found:
            there = ", ".join(sorted(n for n in found if n)) or "none"
            raise BadRobotFile(f"joints: the model has no joint {name!r} (it has: {there})"[:300])
        hinge = found[name]
        if hinge.type != mujoco.mjtJoint.mjJNT_HINGE:
            raise BadRobotFile(f"joints: {name!r} is a {_kind(hinge)} joint, not a hinge")
        if hinges and not _beyond(hinge.parent, hinges[-1].parent):
            raise BadRobotFile(
                f"joints: {name!r} does not move with {hinges[-1].name!r}: list the joints base "
                "to flange, one chain"
            )
        hinges.append(hinge)
    return hinges


def _kind(joint: mujoco.MjsJoint) -> str:
    return mujoco.mjtJoint(joint.type).name.removeprefix("mjJNT_").lower()


def _beyond(body: mujoco.MjsBody, ancestor: mujoco.MjsBody, same: bool = False) -> bool:
    """Whether `body` lies beyond `ancestor` in the tree (or is it, if `same` allows)."""
    if same and body.name == ancestor.name:
        return True
    while body.name != "world":
        body = body.parent
        if body.name == ancestor.name:
            return True
    return False


def _weld_others(spec: mujoco.MjSpec, keep: set[str]) -> None:
    """Delete the joints the description does not name: their bodies stay where they stand."""
    for joint in [joint for joint in spec.joints if joint.name not in keep]:
        spec.delete(joint)


def _place_flange(spec: mujoco.MjSpec, described: RobotFile, last: mujoco.MjsBody) -> None:
    """Check the flange site, or add it on the flange body; either moves with the last joint."""
    flange = described.flange
    sites = {site.name: site for site in spec.sites}
    if flange.site is not None:
        if flange.site not in sites:
            raise BadRobotFile(f"flange.site: the model has no site {flange.site!r}")
        body = sites[flange.site].parent
    else:
        if FLANGE in sites:
            raise BadRobotFile(
                f"flange.body: the model has a site {FLANGE!r}: give it as flange.site instead"
            )
        bodies = {body.name: body for body in spec.bodies}
        if flange.body not in bodies:
            raise BadRobotFile(f"flange.body: the model has no body {flange.body!r}")
        body = bodies[flange.body]
        norm = math.sqrt(sum(v * v for v in flange.quat))
        quat = [v / norm for v in flange.quat]
        body.add_site(name=FLANGE, pos=list(flange.pos), quat=quat, size=[0.01])
    if not _beyond(body, last, same=True):
        field = "flange.site" if flange.site is not None else "flange.body"
        raise BadRobotFile(
            f"{field}: on body {body.name!r}, which the last joint {described.joints[-1]!r} "
            "does not move"
        )


def _first_line(error: Exception) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    said = lines[0].removeprefix("Error: ") if lines else type(error).__name__
    return said[:200]


# --- the plant numbers and the ranges -------------------------------------------------------------


def plant_defaults(described: RobotFile) -> PlantDefaults:
    """The description's plant numbers, those it leaves out under rule "torque-scaled" the iiwa
    14's (models/iiwa14.py, schemas/robot.py) of the joint nearest in torque limit, scaled by the
    ratio of the two limits (an assumption: springs, rotors and friction of the same drive class
    scale with its torque), and Coulomb friction the iiwa's share of the torque limit."""
    plant, torques = described.plant, described.limits.torque
    presets = plant.stiffness_presets
    return PlantDefaults(
        stiffness_presets={
            name: getattr(presets, name)
            if presets is not None
            else _scaled(torques, STIFFNESS_PRESETS[name])
            for name in STIFFNESS_PRESET_NAMES
        },
        stiffness=plant.stiffness,
        spring_damping=plant.spring_damping or _scaled(torques, DEFAULT_SPRING_DAMPING),
        rotor_inertia=plant.rotor_inertia or _scaled(torques, DEFAULT_ROTOR_INERTIA),
        viscous=plant.viscous or _scaled(torques, VISCOUS_FRICTION),
        coulomb=plant.coulomb or tuple(_round(COULOMB_SHARE * t) for t in torques),
    )


def _scaled(torques: tuple[float, ...], iiwa: tuple[float, ...]) -> tuple[float, ...]:
    """Per joint, the iiwa 14's number of the joint nearest in torque limit (on a log scale; of
    two as near, the one nearer the flange: its spring turns the least inertia, the safe side
    for the physics step), times the ratio of the two limits."""
    scaled = []
    for torque in torques:
        distances = [abs(math.log(torque / limit)) for limit in TORQUE_LIMITS]
        nearest = len(distances) - 1 - int(np.argmin(distances[::-1]))
        scaled.append(_round(iiwa[nearest] * torque / TORQUE_LIMITS[nearest]))
    return tuple(scaled)


def _round(value: float) -> float:
    return float(f"{value:.4g}")


def _uncertainty(path: Path, described: RobotFile) -> Text:
    """The ranges robust tuning draws from: the description's file (checked to be a TOML table
    of ranges), or the iiwa 14's with its untold payload scaled to this arm's rated payload."""
    if described.uncertainty is None:
        return Text(f"{described.name}_uncertainty.toml", default_uncertainty(described))
    source = _beside(path, described.uncertainty, "uncertainty")
    try:
        text = read_bounded(source).decode()
        table = load_toml(text)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, BadDocument) as error:
        raise BadRobotFile(f"uncertainty: {_first_line(error)}") from None
    wrong = [key for key, entry in table.items() if not isinstance(entry, dict)]
    if wrong:
        raise BadRobotFile(f"uncertainty: {wrong[0]!r} is not a table of a range")
    return Text(source.name, text)


def default_uncertainty(described: RobotFile) -> str:
    """The iiwa 14's ranges (models/uncertainty.toml) for the described arm, as TOML: its
    untold payload's range scaled by the rated payloads, each range's `why` saying whose it is."""
    table = tomllib.loads(files("gainfarm.models").joinpath("uncertainty.toml").read_text())
    for entry in table.values():
        entry["why"] = f"the iiwa 14's range, taken for {described.name}: {entry['why']}"
    payload = table["payload"]
    payload["high"] = _round(IIWA_PAYLOAD_RANGE * described.rated_payload / RATED_PAYLOAD)
    payload["why"] = (
        f"assumption: the iiwa 14's range ({IIWA_PAYLOAD_RANGE:g} kg of its rated "
        f"{RATED_PAYLOAD:g} kg) scaled to {described.name}'s rated {described.rated_payload:g} kg"
    )
    head = (
        f"# {described.name}'s ranges for robust tuning: the iiwa 14's (models/uncertainty.toml "
        "explains each key), its payload range scaled to this arm's rated payload.\n\n"
    )
    return head + tomli_w.dumps(table)


# --- the checks that build the arm ----------------------------------------------------------------


@contextmanager
def _held(arm: MjcfArm) -> Iterator[None]:
    """`arm` registered under its name for the block (a plant finds its robot by name), then
    whatever was there before: a failing check leaves nothing behind."""
    before = plugins.load(plugins.ROBOTS, arm.name) if arm.name in _sources else None
    _replace(arm.name, arm)
    try:
        yield
    finally:
        if before is None:
            plugins.unregister(plugins.ROBOTS, arm.name)
            resolve.cache_clear()
        else:
            _replace(arm.name, before)


def _replace(name: str, arm: Any) -> None:
    """Register `arm` as `name`; a plant resolved for another arm of that name is forgotten."""
    plugins.register(plugins.ROBOTS, name, arm)
    resolve.cache_clear()


def _check_plant(arm: MjcfArm, described: RobotFile) -> None:
    """The default plant builds, rigid and flexible: the springs of the preset it uses are
    integrable at the default physics step, every per-joint number within the contract's
    bounds."""
    for joints in ("rigid", "flexible"):
        spec = PlantSpec(robot=arm.name, joints=joints)
        try:
            arm.build(spec)
        except PlantError as error:
            raise BadRobotFile(f"plant.{error}") from None
        except ValueError as error:
            raise BadRobotFile(
                f"plant.stiffness: the {described.plant.stiffness!r} preset: "
                f"{_first_line(error)} (a softer preset, or softer springs)"
            ) from None


def _check_reach(arm: MjcfArm) -> None:
    """Every point of the workspace's box (its centre and corners) within the arm's reach with
    the flange pointing down: the last joint's anchor, fixed in the flange's frame, must then be
    within the sum of the distances between consecutive joints' anchors (each fixed in one link)
    of the first joint's, for some heading of the flange about the vertical. Necessary, not
    sufficient: the worker's inverse kinematics has the last word."""
    model = arm.build(PlantSpec(robot=arm.name, joints="rigid", friction=None))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    anchors = np.array([data.xanchor[model.joint(name).id] for name in arm.joint_names])
    reach = float(np.linalg.norm(np.diff(anchors, axis=0), axis=1).sum())
    site = data.site(arm.flange)
    wrist = site.xmat.reshape(3, 3).T @ (anchors[-1] - site.xpos)  # in the flange's frame
    # Flange z down: the last joint's anchor lies -wrist[2] above the point (behind the flange)
    # and `across` off it horizontally, at whatever heading.
    across = float(np.hypot(wrist[0], wrist[1]))
    space = arm.workspace
    corner = "workspace.low/high: corner"
    points = [("workspace.center", space.center), *((corner, c) for c in space.corners())]
    for where, point in points:
        offset = np.asarray(point) - anchors[0]
        horizontal = abs(float(np.hypot(offset[0], offset[1])) - across)
        needed = float(np.hypot(horizontal, offset[2] - wrist[2]))
        if needed > reach + REACH_SLACK:
            raise BadRobotFile(
                f"{where} {tuple(round(v, 3) for v in point)} is out of the arm's reach with the "
                f"flange pointing down ({needed:.3f} m from the first joint, it reaches "
                f"{reach:.3f} m)"
            )
