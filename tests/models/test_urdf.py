"""The URDF and the /tf rotations describe the arm MuJoCo simulates, for every arm whatever its
joints (the iiwa 14's 7, the UR5e's 6): parsed by a real URDF parser (Pinocchio's, urdfdom),
their kinematics and shapes match MuJoCo's at several postures."""

import dataclasses

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from gainfarm import plugins
from gainfarm.models import RIGID_MJCF, robot_of
from gainfarm.models.ur5e import JOINT_NAMES as UR5E_JOINT_NAMES
from gainfarm.models.urdf import WORLD, description, rotations, tree, urdf
from gainfarm.schemas.robot import JOINT_NAMES, POSITION_LIMITS, PlantSpec

ARMS = ("iiwa14", "ur5e")
# The Panda besides, for its kinematics: a fixed body after its last link (Menagerie's
# `attachment`, the hand's mount), and no shapes to draw (its meshes are not vendored).
KINEMATIC = (*ARMS, "panda")
FRAMES = {
    "iiwa14": ["base", *(f"link{i}" for i in range(1, 8)), "flange"],
    # Menagerie's UR5e: ur_description's links, and the flange gainfarm adds (its tool0).
    "ur5e": [
        "base",
        "shoulder_link",
        "upper_arm_link",
        "forearm_link",
        "wrist_1_link",
        "wrist_2_link",
        "wrist_3_link",
        "flange",
    ],
    "panda": [*(f"link{i}" for i in range(8)), "attachment", "flange"],
}
UR5E_JOINTS = UR5E_JOINT_NAMES


def postures(arm: str) -> list[np.ndarray]:
    """Zero, the arm's home, and four draws within its position limits."""
    robot = robot_of(arm)
    limits = np.array(robot.limits.position)
    return [
        np.zeros(len(limits)),
        np.array(robot.workspace.home),
        *np.random.default_rng(17).uniform(-limits, limits, (4, len(limits))),
    ]


def simulated(arm: str) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The rigid arm as the episodes simulate it: the iiwa's hand-written file as it is, the
    others as their robot builds them."""
    if arm == "iiwa14":
        model = mujoco.MjModel.from_xml_string(RIGID_MJCF.read_text())
    else:
        model = robot_of(arm).build(PlantSpec(robot=arm, joints="rigid"))
    return model, mujoco.MjData(model)


def mujoco_poses(arm: str, model, data, q: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each frame's world position and rotation matrix, as MuJoCo computes them at `q`."""
    data.qpos[[model.joint(name).qposadr[0] for name in robot_of(arm).joint_names]] = q
    mujoco.mj_kinematics(model, data)
    poses = {
        name: (data.body(name).xpos.copy(), data.body(name).xmat.reshape(3, 3).copy())
        for name in FRAMES[arm][:-1]
    }
    flange = robot_of(arm).flange
    poses[flange] = (data.site(flange).xpos.copy(), data.site(flange).xmat.reshape(3, 3).copy())
    return poses


def base_of(arm: str, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """Where MuJoCo puts the arm's base, the URDF's root: its position and rotation matrix."""
    base = data.body(FRAMES[arm][0])
    return base.xpos.copy(), base.xmat.reshape(3, 3).copy()


def in_base_frame(
    arm: str, poses: dict[str, tuple[np.ndarray, np.ndarray]]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """`poses` seen from the arm's base, the URDF's root (where the base stands in the world,
    the UR5e's turned a quarter about z, is /tf's world→base, not the URDF's)."""
    origin, turn = poses[FRAMES[arm][0]]
    return {name: (turn.T @ (p - origin), turn.T @ r) for name, (p, r) in poses.items()}


def test_each_arm_s_urdf_names_its_own_joints_and_limits() -> None:
    iiwa, ur5e = (pin.buildModelFromXML(urdf(arm)) for arm in ARMS)
    assert iiwa.name == "iiwa14" and list(iiwa.names)[1:] == list(JOINT_NAMES)
    assert ur5e.name == "ur5e" and ur5e.nq == 6 and tuple(ur5e.names)[1:] == UR5E_JOINTS
    np.testing.assert_allclose(ur5e.effortLimit, (150, 150, 150, 28, 28, 28), atol=1e-12)
    np.testing.assert_allclose(ur5e.velocityLimit, [np.pi] * 6, atol=1e-11)  # 180 °/s
    np.testing.assert_allclose(iiwa.upperPositionLimit, POSITION_LIMITS, atol=1e-12)
    assert urdf() == urdf("iiwa14") == description().urdf  # the default arm's


@pytest.mark.parametrize("arm", KINEMATIC)
def test_pinocchio_reads_the_urdf_as_the_arm_mujoco_simulates(arm: str) -> None:
    model, robot = pin.buildModelFromXML(urdf(arm)), robot_of(arm)
    mj_model, mj_data = simulated(arm)
    assert model.nq == len(robot.joint_names)
    assert list(model.names)[1:] == list(robot.joint_names)
    ranges = np.array([mj_model.joint(name).range for name in robot.joint_names])
    np.testing.assert_allclose(model.lowerPositionLimit, ranges[:, 0], atol=1e-11)
    np.testing.assert_allclose(model.upperPositionLimit, ranges[:, 1], atol=1e-11)
    np.testing.assert_allclose(model.effortLimit, robot.limits.torque, atol=1e-12)
    np.testing.assert_allclose(model.velocityLimit, robot.limits.speed, atol=1e-11)
    data = model.createData()
    for q in postures(arm):
        pin.framesForwardKinematics(model, data, q)
        poses = in_base_frame(arm, mujoco_poses(arm, mj_model, mj_data, q))
        for name, (position, rotation) in poses.items():
            placement = data.oMf[model.getFrameId(name)]
            np.testing.assert_allclose(placement.translation, position, atol=1e-10, err_msg=name)
            np.testing.assert_allclose(placement.rotation, rotation, atol=1e-10, err_msg=name)


# How many URDF visuals each MuJoCo shape is: a capsule is a cylinder and two spheres.
VISUALS = {mujoco.mjtGeom.mjGEOM_CAPSULE: 3, mujoco.mjtGeom.mjGEOM_CYLINDER: 1}


@pytest.mark.parametrize("arm", ARMS)
def test_the_urdf_shapes_are_mujocos_geoms(arm: str) -> None:
    """A capsule is a cylinder (its centre, axis, radius and length) and two spheres at its
    ends; a cylinder is one; every geom of every link is drawn."""
    model = pin.buildModelFromXML(urdf(arm))
    geometry = pin.buildGeomFromUrdfString(model, urdf(arm), pin.GeometryType.VISUAL)
    mj_model, mj_data = simulated(arm)
    q = postures(arm)[-1]
    mujoco_poses(arm, mj_model, mj_data, q)  # MuJoCo's geoms at q
    origin, turn = base_of(arm, mj_data)
    data, geometry_data = model.createData(), geometry.createData()
    pin.updateGeometryPlacements(model, data, geometry, geometry_data, q)
    shapes = {
        obj.name: (obj, geometry_data.oMg[i]) for i, obj in enumerate(geometry.geometryObjects)
    }
    drawn = 0
    for body in FRAMES[arm][:-1]:
        visual = 0  # the body's visuals are {body}_0, _1, ... in its geoms' order
        first = int(mj_model.body(body).geomadr[0])
        for geom in range(first, first + int(mj_model.body(body).geomnum[0])):
            kind = mujoco.mjtGeom(mj_model.geom_type[geom])
            centre = turn.T @ (mj_data.geom_xpos[geom] - origin)  # in the base frame
            axis = turn.T @ mj_data.geom_xmat[geom].reshape(3, 3)[:, 2]
            radius, half = mj_model.geom_size[geom][:2]
            cylinder, placement = shapes[f"{body}_{visual}"]
            assert cylinder.geometry.radius == pytest.approx(radius)
            assert cylinder.geometry.halfLength == pytest.approx(half)
            np.testing.assert_allclose(placement.translation, centre, atol=1e-10)
            np.testing.assert_allclose(placement.rotation[:, 2], axis, atol=1e-10)
            if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                ends = [shapes[f"{body}_{visual + k}"] for k in (1, 2)]
                centres = sorted(tuple(p.translation) for _, p in ends)
                expected = sorted(tuple(centre + s * half * axis) for s in (-1, 1))
                np.testing.assert_allclose(centres, expected, atol=1e-10, err_msg=body)
                assert all(sphere.geometry.radius == pytest.approx(radius) for sphere, _ in ends)
            visual += VISUALS[kind]
            drawn += VISUALS[kind]
    assert len(geometry.geometryObjects) == drawn > 0


@pytest.mark.parametrize("arm", KINEMATIC)
def test_the_tf_rotations_chain_to_mujocos_poses(arm: str) -> None:
    """What /tf carries (the tree's fixed translations, these rotations), composed from the
    world out, is where MuJoCo puts every body and the flange."""
    transforms = tree(arm)
    joints = len(robot_of(arm).joint_names)
    assert [t.child for t in transforms] == FRAMES[arm] and transforms[0].parent == WORLD
    hinged = [t.joint for t in transforms if t.joint is not None]
    assert hinged == list(range(joints)) and transforms[-1].joint is None
    mj_model, mj_data = simulated(arm)
    rows = postures(arm)
    quaternions = rotations(np.array(rows), arm)
    assert description(arm).rotations(np.array(rows)).tobytes() == quaternions.tobytes()
    for row, q in enumerate(rows):
        world = {WORLD: (np.zeros(3), Rotation.identity())}
        for transform, quaternion in zip(transforms, quaternions[row], strict=True):
            position, rotation = world[transform.parent]
            world[transform.child] = (
                position + rotation.apply(transform.translation),
                rotation * Rotation.from_quat(quaternion),  # x y z w, as ROS orders it
            )
        for name, (position, matrix) in mujoco_poses(arm, mj_model, mj_data, q).items():
            np.testing.assert_allclose(world[name][0], position, atol=1e-12, err_msg=name)
            np.testing.assert_allclose(world[name][1].as_matrix(), matrix, atol=1e-12)


def test_a_shape_urdf_has_no_primitive_for_is_drawn_as_its_bounding_box(tmp_path) -> None:
    """A user's arm may draw a link with a mesh or an ellipsoid: the URDF draws each as the box
    MuJoCo bounds it by, placed where MuJoCo places the shape, so that every vertex is in it."""
    text = robot_of("ur5e").mjcf.read_text()
    mesh = '<mesh name="wedge" vertex="0 0 0  0.1 0 0  0 0.05 0  0 0 0.2  0.1 0.05 0.2"/>'
    text = text.replace("<worldbody>", f"<asset>{mesh}</asset>\n  <worldbody>", 1)
    text = text.replace(  # the forearm's capsule a mesh, wrist 3's cylinder an ellipsoid
        '<geom class="collision" size="0.038 0.19" pos="0 0 0.2"/>',
        '<geom type="mesh" mesh="wedge" pos="0 0.01 0.1" quat="1 0.2 0 0" group="3"/>',
    ).replace(
        '<geom class="eef_collision" pos="0 0.08 0" quat="1 1 0 0" size="0.04 0.02"/>',
        '<geom type="ellipsoid" pos="0 0.08 0" quat="1 1 0 0" size="0.04 0.03 0.02"/>',
    )
    (tmp_path / "arm.xml").write_text(text)
    arm = dataclasses.replace(robot_of("ur5e"), name="shaped", mjcf=tmp_path / "arm.xml")
    plugins.register(plugins.ROBOTS, "shaped", arm)
    try:
        model = pin.buildModelFromXML(urdf("shaped"))
        geometry = pin.buildGeomFromUrdfString(model, urdf("shaped"), pin.GeometryType.VISUAL)
        mj_model = arm.build(PlantSpec(robot="shaped", joints="rigid"))
        mj_data = mujoco.MjData(mj_model)
        q = postures("ur5e")[-1]
        mujoco_poses("ur5e", mj_model, mj_data, q)
        data, geometry_data = model.createData(), geometry.createData()
        pin.updateGeometryPlacements(model, data, geometry, geometry_data, q)
        boxes = {
            obj.name: (obj.geometry, geometry_data.oMg[i])
            for i, obj in enumerate(geometry.geometryObjects)
            if isinstance(obj.geometry, pin.hppfcl.Box)
        }
        assert set(boxes) == {"forearm_link_3", "wrist_3_link_0"}  # after a capsule: 0-2
        geom = next(g for g in range(mj_model.ngeom) if mj_model.geom_type[g] == 7)  # the mesh
        box, placement = boxes["forearm_link_3"]
        vertices = mj_model.mesh_vert[: mj_model.mesh_vertnum[0]]  # in the mesh's own frame
        placed = mj_data.geom_xpos[geom] + vertices @ mj_data.geom_xmat[geom].reshape(3, 3).T
        origin, turn = base_of("ur5e", mj_data)
        placed = (placed - origin) @ turn  # in the base frame, the URDF's root
        inside = (placed - placement.translation) @ placement.rotation  # in the box's frame
        assert np.all(np.abs(inside) <= box.halfSide + 1e-6)  # MuJoCo keeps vertices in float32
        assert np.allclose(np.abs(inside).max(axis=0), box.halfSide)  # and tight: the bounds
        ellipsoid = next(g for g in range(mj_model.ngeom) if mj_model.geom_type[g] == 4)
        box, placement = boxes["wrist_3_link_0"]
        np.testing.assert_allclose(box.halfSide, mj_model.geom_size[ellipsoid], atol=1e-12)
        centre = turn.T @ (mj_data.geom_xpos[ellipsoid] - origin)
        np.testing.assert_allclose(placement.translation, centre, atol=1e-10)
    finally:
        plugins.unregister(plugins.ROBOTS, "shaped")
