"""The UR5e plug-in: the conformance kit, and what is its own (6 joints, the cited limits, the
flexible model's names, the flange pointing down at home, its ranges file)."""

import math

import mujoco
import numpy as np
import pytest

from gainfarm import plugins
from gainfarm.analytic.tuning.plants import ranges
from gainfarm.models import robot_of, ur5e
from gainfarm.schemas.robot import PlantSpec, Robot
from gainfarm.testing.robots import RobotChecks
from gainfarm.worker.trajectories import TOOL_DOWN

NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)


@pytest.mark.slow
class TestTheUr5ePassesTheKit(RobotChecks):
    @pytest.fixture
    def robot(self) -> Robot:
        return ur5e.ROBOT


def test_the_ur5e_is_installed_as_a_six_joint_robot_with_the_ros_names() -> None:
    robot = robot_of("ur5e")
    assert robot is ur5e.ROBOT and isinstance(robot, Robot)
    assert "ur5e" in plugins.builtin_names(plugins.ROBOTS)
    assert robot.joint_names == NAMES


def test_the_limits_are_the_cited_numbers() -> None:
    limits = ur5e.ROBOT.limits
    assert limits.torque == (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
    assert limits.speed == pytest.approx((math.radians(180.0),) * 6)
    two_pi = 2 * math.pi
    assert limits.position == pytest.approx((two_pi, two_pi, math.pi, two_pi, two_pi, two_pi))
    assert limits.acceleration == (10.0, 10.0, 10.0, 15.0, 15.0, 15.0)  # an assumption
    assert ur5e.ROBOT.rated_payload == 5.0
    assert ur5e.ROBOT.torque_interface.adds_gravity  # direct_torque compensates gravity


def test_the_flexible_model_names_each_joint_s_motor_and_spring() -> None:
    model = ur5e.ROBOT.build(PlantSpec(robot="ur5e", joints="flexible"))
    names = [model.joint(j).name for j in range(model.njnt)]
    assert names == [f"{name}_{side}" for name in NAMES for side in ("motor", "spring")]
    driven = [model.joint(model.actuator_trnid[a, 0]).name for a in range(model.nu)]
    assert driven == [f"{name}_motor" for name in NAMES]
    assert [model.actuator(a).name for a in range(model.nu)] == list(NAMES)


def test_the_default_stiffness_integrates_at_two_substeps_and_the_stiff_preset_needs_more() -> None:
    robot = ur5e.ROBOT
    assert robot.min_substeps(PlantSpec(robot="ur5e")) <= 2
    stiff = PlantSpec(robot="ur5e", stiffness=robot.plant_defaults.stiffness_presets["stiff"])
    with pytest.raises(ValueError, match=r"substeps=2 is too few .* needs substeps >= \d+"):
        robot.build(stiff)
    robot.build(stiff.model_copy(update={"substeps": robot.min_substeps(stiff)}))


def test_at_home_the_flange_points_down_as_the_trajectories_hold_the_tool() -> None:
    robot = ur5e.ROBOT
    model = robot.build(PlantSpec(robot="ur5e", joints="rigid"))
    data = mujoco.MjData(model)
    data.qpos[:] = robot.workspace.home
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.site(robot.flange).xmat.reshape(3, 3), TOOL_DOWN, atol=1e-6)
    # 0.1 m below wrist 3 (ur_description's tool0)
    wrist = data.body("wrist_3_link").xpos
    np.testing.assert_allclose(
        data.site(robot.flange).xpos, wrist - np.array([0, 0, 0.1]), atol=1e-6
    )


def test_the_ranges_file_reads_and_scales_the_payload_to_the_rated_one() -> None:
    table = ranges(ur5e.ROBOT.uncertainty.read_text())
    assert table["payload"].high == pytest.approx(1.0)
    assert table["payload"].high <= ur5e.ROBOT.rated_payload
