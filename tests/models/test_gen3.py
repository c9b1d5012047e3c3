"""The Kinova Gen3 plug-in: the conformance kit, and what is its own (7 joints named as
ros2_kortex names them, the cited limits, the flexible model's names, the flange pointing down
at home, its ranges file)."""

import math

import mujoco
import numpy as np
import pytest

from gainfarm import plugins
from gainfarm.analytic.tuning.plants import ranges
from gainfarm.models import gen3, robot_of
from gainfarm.schemas.robot import PlantSpec, Robot
from gainfarm.testing.robots import RobotChecks
from gainfarm.worker.trajectories import TOOL_DOWN

NAMES = tuple(f"joint_{i}" for i in range(1, 8))


@pytest.mark.slow
class TestTheGen3PassesTheKit(RobotChecks):
    @pytest.fixture
    def robot(self) -> Robot:
        return gen3.ROBOT


def test_the_gen3_is_installed_as_a_seven_joint_robot_with_the_ros_names() -> None:
    robot = robot_of("gen3")
    assert robot is gen3.ROBOT and isinstance(robot, Robot)
    assert "gen3" in plugins.builtin_names(plugins.ROBOTS)
    assert robot.joint_names == NAMES


def test_the_limits_are_the_cited_numbers() -> None:
    limits = gen3.ROBOT.limits
    assert limits.torque == (39.0,) * 4 + (9.0,) * 3
    assert limits.speed == (1.3963,) * 4 + (1.2218,) * 3
    endless = 2 * math.pi  # an assumption for the joints that turn without end
    degrees = [math.degrees(v) for v in limits.position]
    assert degrees == pytest.approx([360.0, 128.9, 360.0, 147.8, 360.0, 120.3, 360.0])
    assert limits.position[0] == endless
    assert limits.acceleration == (4.94,) * 4 + (9.5,) * 3
    assert gen3.ROBOT.rated_payload == 4.0
    assert not gen3.ROBOT.torque_interface.adds_gravity  # low-level torque: the command is all


def test_the_flexible_model_names_each_joint_s_motor_and_spring() -> None:
    model = gen3.ROBOT.build(PlantSpec(robot="gen3", joints="flexible"))
    names = [model.joint(j).name for j in range(model.njnt)]
    assert names == [f"{name}_{side}" for name in NAMES for side in ("motor", "spring")]
    driven = [model.joint(model.actuator_trnid[a, 0]).name for a in range(model.nu)]
    assert driven == [f"{name}_motor" for name in NAMES]


def test_the_default_stiffness_integrates_at_two_substeps_and_the_stiff_preset_needs_more() -> None:
    robot = gen3.ROBOT
    assert robot.min_substeps(PlantSpec(robot="gen3")) <= 2
    stiff = PlantSpec(robot="gen3", stiffness=robot.plant_defaults.stiffness_presets["stiff"])
    with pytest.raises(ValueError, match=r"substeps=2 is too few .* needs substeps >= \d+"):
        robot.build(stiff)


def test_at_home_the_flange_points_down_as_the_trajectories_hold_the_tool() -> None:
    robot = gen3.ROBOT
    model = robot.build(PlantSpec(robot="gen3", joints="rigid"))
    data = mujoco.MjData(model)
    data.qpos[:] = robot.workspace.home
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.site(robot.flange).xmat.reshape(3, 3), TOOL_DOWN, atol=1e-4)
    # ros2_kortex's end_effector_link, where Menagerie puts its pinch site
    np.testing.assert_allclose(data.site(robot.flange).xpos, data.site("pinch_site").xpos)
    np.testing.assert_allclose(data.site(robot.flange).xpos, robot.workspace.center, atol=0.002)


def test_the_ranges_file_reads_and_scales_the_payload_to_the_rated_one() -> None:
    table = ranges(gen3.ROBOT.uncertainty.read_text())
    assert table["payload"].high == pytest.approx(0.9)
