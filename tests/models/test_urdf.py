"""The URDF and the /tf rotations describe the arm MuJoCo simulates: parsed by a real URDF parser
(Pinocchio's, urdfdom), their kinematics and shapes match MuJoCo's at several postures."""

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from gainfarm.models import RIGID_MJCF
from gainfarm.models.urdf import WORLD, rotations, tree, urdf
from gainfarm.schemas.robot import JOINT_NAMES, POSITION_LIMITS, SPEED_LIMITS, TORQUE_LIMITS

FRAMES = ["base", *(f"link{i}" for i in range(1, 8)), "flange"]
HOME = (0.0, 0.785398, 0.0, -1.5708, 0.0, 0.0, 0.0)
LIMITS = np.array(POSITION_LIMITS)
POSTURES = [
    np.zeros(7),
    np.array(HOME),
    *np.random.default_rng(17).uniform(-LIMITS, LIMITS, (4, 7)),
]


@pytest.fixture(scope="module")
def simulated() -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(RIGID_MJCF.read_text())
    return model, mujoco.MjData(model)


def mujoco_poses(simulated, q: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each frame's world position and rotation matrix, as MuJoCo computes them at `q`."""
    model, data = simulated
    data.qpos[[model.joint(name).qposadr[0] for name in JOINT_NAMES]] = q
    mujoco.mj_kinematics(model, data)
    poses = {
        name: (data.body(name).xpos.copy(), data.body(name).xmat.reshape(3, 3).copy())
        for name in FRAMES[:-1]
    }
    poses["flange"] = (
        data.site("flange").xpos.copy(),
        data.site("flange").xmat.reshape(3, 3).copy(),
    )
    return poses


def test_pinocchio_reads_the_urdf_as_the_arm_mujoco_simulates(simulated) -> None:
    model = pin.buildModelFromXML(urdf())
    assert model.nq == 7 and list(model.names)[1:] == list(JOINT_NAMES)
    np.testing.assert_allclose(model.upperPositionLimit, POSITION_LIMITS, atol=1e-12)
    np.testing.assert_allclose(model.lowerPositionLimit, -LIMITS, atol=1e-12)
    np.testing.assert_allclose(model.effortLimit, TORQUE_LIMITS, atol=1e-12)
    np.testing.assert_allclose(model.velocityLimit, SPEED_LIMITS, atol=1e-11)
    data = model.createData()
    for q in POSTURES:
        pin.framesForwardKinematics(model, data, q)
        for name, (position, rotation) in mujoco_poses(simulated, q).items():
            placement = data.oMf[model.getFrameId(name)]
            np.testing.assert_allclose(placement.translation, position, atol=1e-10, err_msg=name)
            np.testing.assert_allclose(placement.rotation, rotation, atol=1e-10, err_msg=name)


def test_the_urdf_shapes_are_mujocos_geoms(simulated) -> None:
    """A capsule is a cylinder (its centre, axis, radius and length) and two spheres at its ends."""
    model = pin.buildModelFromXML(urdf())
    geometry = pin.buildGeomFromUrdfString(model, urdf(), pin.GeometryType.VISUAL)
    mj_model, mj_data = simulated
    q = POSTURES[-1]
    mujoco_poses(simulated, q)  # MuJoCo's geoms at q
    data, geometry_data = model.createData(), geometry.createData()
    pin.updateGeometryPlacements(model, data, geometry, geometry_data, q)
    shapes = {
        obj.name: (obj, geometry_data.oMg[i]) for i, obj in enumerate(geometry.geometryObjects)
    }
    for body in FRAMES[:-1]:
        assert mj_model.body(body).geomnum[0] == 1  # so its visuals are {body}_0, _1, _2
        geom = mj_data.geom(int(mj_model.body(body).geomadr[0]))
        radius, half = mj_model.geom_size[geom.id][:2]
        axis = geom.xmat.reshape(3, 3)[:, 2]
        cylinder, placement = shapes[f"{body}_0"]
        assert cylinder.geometry.radius == pytest.approx(radius)
        assert cylinder.geometry.halfLength == pytest.approx(half)
        np.testing.assert_allclose(placement.translation, geom.xpos, atol=1e-10, err_msg=body)
        np.testing.assert_allclose(placement.rotation[:, 2], axis, atol=1e-10, err_msg=body)
        if mj_model.geom_type[geom.id] == mujoco.mjtGeom.mjGEOM_CAPSULE:
            ends = [shapes[f"{body}_{k}"] for k in (1, 2)]
            centres = sorted(tuple(p.translation) for _, p in ends)
            expected = sorted(tuple(geom.xpos + s * half * axis) for s in (-1, 1))
            np.testing.assert_allclose(centres, expected, atol=1e-10, err_msg=body)
            assert all(sphere.geometry.radius == pytest.approx(radius) for sphere, _ in ends)
    assert len(geometry.geometryObjects) == 2 + 3 * 6  # two cylinders, six capsules


def test_the_tf_rotations_chain_to_mujocos_poses(simulated) -> None:
    """What /tf carries (the tree's fixed translations, these rotations), composed from the
    world out, is where MuJoCo puts every body and the flange."""
    transforms = tree()
    assert [t.child for t in transforms] == FRAMES and transforms[0].parent == WORLD
    assert [t.joint for t in transforms] == [None, *range(7), None]
    quaternions = rotations(np.array(POSTURES))
    for row, q in enumerate(POSTURES):
        world = {WORLD: (np.zeros(3), Rotation.identity())}
        for transform, quaternion in zip(transforms, quaternions[row], strict=True):
            position, rotation = world[transform.parent]
            world[transform.child] = (
                position + rotation.apply(transform.translation),
                rotation * Rotation.from_quat(quaternion),  # x y z w, as ROS orders it
            )
        for name, (position, matrix) in mujoco_poses(simulated, q).items():
            np.testing.assert_allclose(world[name][0], position, atol=1e-12, err_msg=name)
            np.testing.assert_allclose(world[name][1].as_matrix(), matrix, atol=1e-12)
