"""An arm as ROS tools see a robot: a URDF, and the transforms of its links for /tf.

Both come from the model the episodes simulate, the robot's own (`robot.describe`, its rigid
variant), compiled by MuJoCo, so they never drift from what the episodes simulate, whichever the
arm and however many its joints. MuJoCo writes MJCF only, and the converters that exist turn
every geom into a mesh file beside the URDF; an episode log must carry its description whole
(ROS tools read it from the /robot_description topic), so this module writes the primitive shapes
of the model as URDF primitives: a capsule is a cylinder between two spheres, and a shape URDF
has no primitive for (a mesh, an ellipsoid) is drawn as its bounding box, as MuJoCo computes it.

The description is for drawing the arm and for its kinematics: links, the robot's hinges (named
as the joint states name them, `robot.joint_names`) with their limits (the model's range, the
data sheet's torque and speed), the flange, and each link's shapes. It has no inertials: those
depend on the plant an episode ran (`PlantSpec`), not on the arm.

Every number is written rounded to 12 decimals (a picometre, a picoradian), so that the text, and
with it every episode log's SHA-256, is the same on every machine whatever the last bit of a
libm's atan2.
"""

import warnings
from dataclasses import dataclass
from functools import cache, partial
from xml.etree import ElementTree

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from gainfarm.models.robots import robot_of
from gainfarm.schemas.episode_log import Frame, RobotDescription
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec

WORLD = "world"  # the frame the episode's points are in: MuJoCo's world, the robot's base frame
DECIMALS = 12


@dataclass(frozen=True)
class Transform:
    """One parent→child transform of the tree: fixed, or turned by a hinge about `axis`."""

    parent: str
    child: str
    translation: tuple[float, float, float]  # m, in the parent's frame
    rotation: tuple[float, float, float, float]  # w x y z: the child's frame at joint angle 0
    joint: int | None = None  # which of the robot's joints (0-based) turns the child; None: fixed
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)  # the hinge's, in the child's frame
    body: int | None = None  # the MuJoCo body it is (None: the flange, a site)


@cache
def _model(robot: str) -> mujoco.MjModel:
    """The rigid arm `robot` names: every plant of it has its bodies, geoms and hinges."""
    return robot_of(robot).describe(PlantSpec(robot=robot, joints="rigid")).compile()


def _body_name(model: mujoco.MjModel, body: int) -> str:
    """A body's link name: its own, or one made of its number if the model leaves it unnamed."""
    return model.body(body).name or f"body{body}"


@cache
def tree(robot: str = DEFAULT_ROBOT) -> tuple[Transform, ...]:
    """world→base, each link from its parent (turned by its hinge), the last link→flange.
    ValueError, in one line, for a model URDF cannot say: a body turned by several joints or by
    one that is not a hinge of the robot at its origin, or several roots."""
    model, arm = _model(robot), robot_of(robot)
    transforms = []
    for body in range(1, model.nbody):
        above = int(model.body_parentid[body])
        parent = WORLD if above == 0 else _body_name(model, above)
        joints = range(model.body_jntadr[body], model.body_jntadr[body] + model.body_jntnum[body])
        joint = None
        if len(joints) > 1:
            raise ValueError(f"body {_body_name(model, body)!r} has {len(joints)} joints, not one")
        if len(joints) == 1:
            hinge = model.joint(joints[0])
            if hinge.type != mujoco.mjtJoint.mjJNT_HINGE or np.any(hinge.pos != 0):
                raise ValueError(f"joint {hinge.name!r} is not a hinge at its body's origin")
            if hinge.name not in arm.joint_names:
                raise ValueError(f"joint {hinge.name!r} is none of {robot}'s joints")
            joint = arm.joint_names.index(hinge.name)
        transforms.append(
            Transform(
                parent,
                _body_name(model, body),
                _triple(model.body_pos[body]),
                _quadruple(model.body_quat[body]),
                joint,
                _triple(model.jnt_axis[joints[0]]) if joint is not None else (0.0, 0.0, 1.0),
                body,
            )
        )
    roots = [t.child for t in transforms if t.parent == WORLD]
    if len(roots) != 1:
        raise ValueError(f"{robot}: {len(roots)} bodies on the world, not one root: {roots}")
    flange = model.site(arm.flange)
    transforms.append(
        Transform(
            _body_name(model, int(flange.bodyid[0])),
            arm.flange,
            _triple(flange.pos),
            _quadruple(flange.quat),
        )
    )
    return tuple(transforms)


def rotations(q: np.ndarray, robot: str = DEFAULT_ROBOT) -> np.ndarray:
    """(n, len(tree(robot)), 4): each transform's rotation (x y z w, as ROS orders a quaternion)
    at each of the n rows of joint angles `q` (n, the robot's joints): the fixed rotation, then
    the hinge's turn.

    The Hamilton product is written out, for all hinges at once: scipy's Rotation takes 2 ms to
    compose a 5 s episode's /tf (251 messages of 9 transforms), a fifth of writing its whole
    log; a product per hinge took 0.24 ms, this 0.1 ms (tested against MuJoCo). Each number is
    the same expression of the same operands as per hinge, so the same bits.
    """
    q = np.asarray(q, dtype=float)
    fixed, hinged, joints, axes = _turns(robot)
    out = np.empty((len(q), len(fixed), 4))
    out[:, ~hinged] = fixed[~hinged][:, [1, 2, 3, 0]]
    half = q[:, joints] / 2  # (n, hinges)
    c, s = np.cos(half), np.sin(half)
    ax, ay, az = (s * component for component in axes.T)
    w, x, y, z = fixed[hinged].T
    out[:, hinged] = np.stack(
        (
            w * ax + x * c + y * az - z * ay,
            w * ay - x * az + y * c + z * ax,
            w * az + x * ay - y * ax + z * c,
            w * c - x * ax - y * ay - z * az,
        ),
        axis=-1,
    )
    return out


@cache
def _turns(robot: str) -> tuple[np.ndarray, np.ndarray, list[int], np.ndarray]:
    """What rotations needs of the tree: each transform's fixed rotation (w x y z), which
    transforms a hinge turns, and the hinges' joints and axes, in tree order."""
    transforms = tree(robot)
    fixed = np.array([transform.rotation for transform in transforms])
    hinged = np.array([transform.joint is not None for transform in transforms])
    turned = [transform for transform in transforms if transform.joint is not None]
    joints = [transform.joint for transform in turned]
    axes = np.array([transform.axis for transform in turned], dtype=float).reshape(-1, 3)
    return fixed, hinged, joints, axes


@cache
def description(robot: str = DEFAULT_ROBOT) -> RobotDescription:
    """The arm `robot` names as every episode log of it draws it for ROS tools: what the log's
    writer is given (the plant's robot: `description(spec.plant.robot)`)."""
    frames = tuple(Frame(t.parent, t.child, t.translation) for t in tree(robot))
    return RobotDescription(urdf(robot), frames, partial(rotations, robot=robot))


@cache
def urdf(robot: str = DEFAULT_ROBOT) -> str:
    """The URDF of the arm `robot` names (root link: its base), as ROS tools read it from
    /robot_description; the robot's name is the URDF's."""
    model, arm = _model(robot), robot_of(robot)
    root = ElementTree.Element("robot", name=robot)
    for transform in tree(robot):
        link = ElementTree.SubElement(root, "link", name=transform.child)
        if transform.body is not None:
            link.extend(_visuals(model, transform.body))
        if transform.parent == WORLD:
            continue  # the root: where the robot stands is /tf's world→base, not the URDF's
        if transform.joint is None:
            joint = ElementTree.SubElement(
                root, "joint", name=f"{transform.child}_joint", type="fixed"
            )
        else:
            name = arm.joint_names[transform.joint]
            joint = ElementTree.SubElement(root, "joint", name=name, type="revolute")
        ElementTree.SubElement(joint, "parent", link=transform.parent)
        ElementTree.SubElement(joint, "child", link=transform.child)
        joint.append(_origin(transform.translation, transform.rotation))
        if transform.joint is not None:
            hinge = model.joint(name)
            ElementTree.SubElement(joint, "axis", xyz=_numbers(transform.axis))
            ElementTree.SubElement(
                joint,
                "limit",
                lower=_number(hinge.range[0]),
                upper=_number(hinge.range[1]),
                effort=_number(arm.limits.torque[transform.joint]),
                velocity=_number(arm.limits.speed[transform.joint]),
            )
    ElementTree.indent(root)
    return '<?xml version="1.0"?>\n' + ElementTree.tostring(root, encoding="unicode") + "\n"


# What a plane or a height field is in an arm's model: the ground, or scenery; not the arm.
_SCENERY = (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)


def _visuals(model: mujoco.MjModel, body: int) -> list[ElementTree.Element]:
    """The body's geoms as URDF visuals: a capsule as a cylinder and its two end spheres; a shape
    URDF has no primitive for (a mesh, an ellipsoid) as its bounding box, MuJoCo's."""
    visuals = []
    for geom in range(
        model.body_geomadr[body], model.body_geomadr[body] + model.body_geomnum[body]
    ):
        kind, size = mujoco.mjtGeom(model.geom_type[geom]), model.geom_size[geom]
        position, quat = model.geom_pos[geom], model.geom_quat[geom]
        colour = model.geom_rgba[geom]
        if kind in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
            radius, half = size[0], size[1]
            visuals.append(
                _visual(position, quat, "cylinder", colour, radius=radius, length=2 * half)
            )
            if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                axis = Rotation.from_quat(quat, scalar_first=True).apply([0.0, 0.0, half])
                for end in (position - axis, position + axis):
                    visuals.append(_visual(end, quat, "sphere", colour, radius=radius))
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            visuals.append(_visual(position, quat, "sphere", colour, radius=size[0]))
        elif kind == mujoco.mjtGeom.mjGEOM_BOX:
            visuals.append(_visual(position, quat, "box", colour, size=_numbers(2 * size)))
        elif kind not in _SCENERY:
            # geom_aabb: the box's centre and half-sizes, in the geom's own frame.
            centre, half_sizes = model.geom_aabb[geom][:3], model.geom_aabb[geom][3:]
            offset = Rotation.from_quat(quat, scalar_first=True).apply(centre)
            visuals.append(
                _visual(position + offset, quat, "box", colour, size=_numbers(2 * half_sizes))
            )
    return visuals


def _visual(
    position: np.ndarray, quat: np.ndarray, shape: str, colour: np.ndarray, **dimensions: object
) -> ElementTree.Element:
    visual = ElementTree.Element("visual")
    visual.append(_origin(_triple(position), _quadruple(quat)))
    geometry = ElementTree.SubElement(visual, "geometry")
    ElementTree.SubElement(
        geometry,
        shape,
        {
            key: value if isinstance(value, str) else _number(value)
            for key, value in dimensions.items()
        },
    )
    visual.append(_material(colour))
    return visual


def _origin(xyz: tuple[float, ...], quat: tuple[float, ...]) -> ElementTree.Element:
    """URDF's origin: xyz, and rpy (fixed axes x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll))."""
    with warnings.catch_warnings():
        # At a pitch of ±90° (UR5e's links) roll and yaw are one turn: SciPy warns, sets the
        # yaw to 0 and puts the turn in the roll, which is the same rotation (the tests check).
        warnings.simplefilter("ignore", UserWarning)
        rpy = Rotation.from_quat(quat, scalar_first=True).as_euler("xyz")
    return ElementTree.Element("origin", xyz=_numbers(xyz), rpy=_numbers(rpy))


def _triple(values: np.ndarray) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return x, y, z


def _quadruple(values: np.ndarray) -> tuple[float, float, float, float]:
    w, x, y, z = (float(v) for v in values)
    return w, x, y, z


def _number(value: float) -> str:
    rounded = round(float(value), DECIMALS) + 0.0  # + 0.0: no "-0"
    return np.format_float_positional(rounded, trim="-")


def _numbers(values: object) -> str:
    return " ".join(_number(v) for v in np.asarray(values, dtype=float).ravel())


def _material(colour: np.ndarray) -> ElementTree.Element:
    """A colour, named by itself (MuJoCo keeps colours as float32: 4 digits say what the MJCF
    says)."""
    rgba = [f"{float(c):.4g}" for c in colour]
    material = ElementTree.Element("material", name="rgba_" + "_".join(rgba))
    ElementTree.SubElement(material, "color", rgba=" ".join(rgba))
    return material
