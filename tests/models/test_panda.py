"""The Franka Emika Panda plug-in: the conformance kit, and what is its own (7 joints named as
franka_description names them, the cited limits and asymmetric ranges, Franka's stiffness gains,
the flexible model's names, the flange pointing down at home, its ranges file)."""

import mujoco
import numpy as np
import pytest

from gainfarm import plugins
from gainfarm.analytic.tuning.plants import ranges
from gainfarm.models import panda, robot_of
from gainfarm.schemas.robot import PlantSpec, Robot
from gainfarm.testing.robots import RobotChecks
from gainfarm.worker.trajectories import TOOL_DOWN

NAMES = tuple(f"panda_joint{i}" for i in range(1, 8))
RANGES = (
    (-2.8973, 2.8973),
    (-1.7628, 1.7628),
    (-2.8973, 2.8973),
    (-3.0718, -0.0698),
    (-2.8973, 2.8973),
    (-0.0175, 3.7525),
    (-2.8973, 2.8973),
)


@pytest.mark.slow
class TestThePandaPassesTheKit(RobotChecks):
    @pytest.fixture
    def robot(self) -> Robot:
        return panda.ROBOT

    @pytest.mark.xfail(
        strict=True,
        reason="JointLimits.position is symmetric (±position); the Panda's joint 4 turns from "
        "-3.0718 to -0.0698 rad, which its hinge keeps: the contract needs a low bound",
    )
    def test_builds(self, robot: Robot) -> None:
        super().test_builds(robot)


def test_the_panda_is_installed_as_a_seven_joint_robot_with_the_ros_names() -> None:
    robot = robot_of("panda")
    assert robot is panda.ROBOT and isinstance(robot, Robot)
    assert plugins.builtin_names(plugins.ROBOTS)[:2] == ("iiwa14", "panda")
    assert robot.joint_names == NAMES


def test_the_limits_are_the_cited_numbers_and_the_hinges_keep_the_asymmetric_ranges() -> None:
    limits = panda.ROBOT.limits
    assert limits.torque == (87.0,) * 4 + (12.0,) * 3
    assert limits.speed == (2.175,) * 4 + (2.61,) * 3
    assert limits.acceleration == (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)
    assert limits.position == tuple(max(-low, high) for low, high in RANGES)
    for kind in ("rigid", "flexible"):
        model = panda.ROBOT.build(PlantSpec(robot="panda", joints=kind))
        driven = model.actuator_trnid[:, 0]
        np.testing.assert_allclose(model.jnt_range[driven], RANGES)
        np.testing.assert_allclose(model.actuator_ctrlrange[:, 1], limits.torque)
    assert panda.ROBOT.rated_payload == 3.0
    assert panda.ROBOT.torque_interface.adds_gravity  # libfranka: gravity is the robot's


def test_the_stiffness_gains_are_libfranka_s_example_s() -> None:
    assert panda.ROBOT.default_gains.kp == (600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0)


def test_the_flexible_model_names_each_joint_s_motor_and_spring() -> None:
    model = panda.ROBOT.build(PlantSpec(robot="panda", joints="flexible"))
    names = [model.joint(j).name for j in range(model.njnt)]
    assert names == [f"{name}_{side}" for name in NAMES for side in ("motor", "spring")]


def test_the_default_stiffness_integrates_at_two_substeps() -> None:
    assert panda.ROBOT.min_substeps(PlantSpec(robot="panda")) <= 2


def test_at_home_the_flange_points_down_over_the_default_centre() -> None:
    robot = panda.ROBOT
    model = robot.build(PlantSpec(robot="panda", joints="rigid"))
    data = mujoco.MjData(model)
    data.qpos[:] = robot.workspace.home
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.site(robot.flange).xmat.reshape(3, 3), TOOL_DOWN, atol=1e-4)
    np.testing.assert_allclose(data.site(robot.flange).xpos, robot.workspace.center, atol=1e-4)
    # franka_description's panda_link8, where Menagerie puts its attachment site
    np.testing.assert_allclose(data.site(robot.flange).xpos, data.site("attachment_site").xpos)


def test_the_ranges_file_reads_and_scales_the_payload_to_the_rated_one() -> None:
    table = ranges(panda.ROBOT.uncertainty.read_text())
    assert table["payload"].high == pytest.approx(0.6)
