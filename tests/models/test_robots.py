"""The one lookup from a plant to its robot; the iiwa 14, the first gainfarm.robots plug-in."""

import pytest
from pydantic import ValidationError

from gainfarm import plugins
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.models import build_spec, compile_model, iiwa14, robot_of
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.robot import (
    DEFAULT_ROBOT,
    JOINT_NAMES,
    ROBOT_PATTERN,
    TORQUE_LIMITS,
    PlantSpec,
    Robot,
    Workspace,
)
from gainfarm.testing.robots import RobotChecks


class TestTheIiwa14PassesTheKit(RobotChecks):
    @pytest.fixture
    def robot(self) -> Robot:
        return iiwa14.ROBOT


def test_the_plant_s_robot_is_the_iiwa14_by_default_and_found_by_its_name() -> None:
    assert PlantSpec().robot == DEFAULT_ROBOT == "iiwa14"
    assert plugins.builtin_names(plugins.ROBOTS)[0] == "iiwa14"  # the default first
    assert robot_of(PlantSpec()) is robot_of("iiwa14") is iiwa14.ROBOT
    assert isinstance(iiwa14.ROBOT, Robot)


def test_the_iiwa14_declares_the_facts_the_code_reads() -> None:
    robot = robot_of()
    assert robot.joint_names == JOINT_NAMES and robot.limits.torque == TORQUE_LIMITS
    assert robot.default_gains == DEFAULT_GAINS
    assert robot.workspace.center == (0.55, 0.0, 0.35)  # the default trajectory's centre


def test_the_models_builders_are_the_named_robot_s() -> None:
    spec = PlantSpec(joints="rigid", substeps=1)
    assert compile_model(spec) is iiwa14.compile_model(spec)  # the robot's cache, not a copy
    assert build_spec(spec).to_xml() == iiwa14.build_spec(spec).to_xml()


def test_a_robot_not_here_is_refused_in_one_line_naming_what_there_is() -> None:
    with pytest.raises(plugins.PluginError) as refused:
        compile_model(PlantSpec(robot="xarm7"))
    there = ", ".join(plugins.names(plugins.ROBOTS))
    assert str(refused.value) == (
        f"gainfarm.robots: no plug-in named 'xarm7' here (there are {there}); "
        "install the distribution that provides it"
    )


def test_a_plug_in_that_is_not_a_robot_is_refused_naming_what_it_lacks() -> None:
    plugins.register(plugins.ROBOTS, "half-arm", Workspace((0.0,), (0, 0, 0), (0, 0, 0), (0, 0, 0)))
    try:
        with pytest.raises(plugins.PluginError, match=r"'half-arm' is a Workspace, not a robot"):
            robot_of("half-arm")
    finally:
        plugins.unregister(plugins.ROBOTS, "half-arm")


def test_the_contract_checks_a_robot_name_s_form_only() -> None:
    assert ROBOT_PATTERN == plugins.NAME_PATTERN
    assert PlantSpec(robot="ur5e").robot == "ur5e"  # may be installed on the workers
    for bad in ("UR5e", "", "a/b", "x" * 33, 7):
        with pytest.raises(ValidationError, match="robot"):
            PlantSpec(robot=bad)


def test_a_run_on_a_robot_not_here_is_refused_naming_it() -> None:
    with pytest.raises(ValidationError, match="no plug-in named 'xarm7' here"):
        RunConfig(plant=PlantSpec(robot="xarm7"))
    assert RunConfig().plant.robot == "iiwa14"
