"""The robot description file's form: a valid one read whole, every problem refused in one line
naming its field."""

import copy
from typing import Any

import pytest
import tomli_w

from gainfarm.schemas.robot_file import (
    MAX_FILE_BYTES,
    BadRobotFile,
    RobotFile,
    read_robot_file,
)

JOINTS = ["j1", "j2", "j3", "j4", "j5", "j6"]

VALID: dict[str, Any] = {
    "name": "my_arm",
    "model": "arm.xml",
    "joints": JOINTS,
    "rated_payload": 5.0,
    "flange": {"body": "wrist", "pos": [0.0, 0.1, 0.0], "quat": [0.5, -0.5, 0.5, 0.5]},
    "limits": {
        "torque": [150.0, 150.0, 150.0, 28.0, 28.0, 28.0],
        "speed": [3.14] * 6,
        "position": [6.28, 6.28, 3.14, 6.28, 6.28, 6.28],
        "acceleration": [10.0, 10.0, 10.0, 15.0, 15.0, 15.0],
    },
    "default_gains": {"kp": [1000.0] * 3 + [187.0] * 3, "kd": [10.0] * 3 + [1.87] * 3},
    "torque_interface": {
        "name": "direct torque",
        "adds_gravity": True,
        "description": "the controller adds its gravity model",
    },
    "workspace": {
        "home": [-1.57, -1.57, 1.57, -1.57, -1.57, 0.0],
        "center": [0.45, 0.13, 0.35],
        "low": [0.4, 0.0, 0.3],
        "high": [0.5, 0.25, 0.4],
    },
    "plant": {"rule": "torque-scaled", "source": "assumption: the iiwa 14's, scaled"},
}

EXPLICIT_PLANT = {
    "source": "measured on our arm",
    "stiffness": "soft",
    "stiffness_presets": {
        "soft": [4000.0] * 6,
        "medium": [20000.0] * 6,
        "stiff": [50000.0] * 6,
    },
    "spring_damping": [10.0] * 6,
    "rotor_inertia": [0.1] * 6,
    "viscous": [0.3] * 6,
    "coulomb": [2.0] * 6,
}


def with_(path: str, value: Any) -> dict[str, Any]:
    """VALID with the dotted `path` set to `value` (deleted if value is DELETE)."""
    table = copy.deepcopy(VALID)
    *parents, last = path.split(".")
    here = table
    for part in parents:
        here = here[part]
    if value is DELETE:
        del here[last]
    else:
        here[last] = copy.deepcopy(value)
    return table


DELETE = object()


def read(table: dict[str, Any]) -> RobotFile:
    return read_robot_file(tomli_w.dumps(table).encode())


def refused(table: dict[str, Any]) -> str:
    with pytest.raises(BadRobotFile) as error:
        read(table)
    message = str(error.value)
    assert "\n" not in message
    return message


def test_a_valid_description_is_read_whole() -> None:
    described = read(VALID)
    assert described.name == "my_arm"
    assert described.joints == tuple(JOINTS)
    assert described.flange.body == "wrist" and described.flange.site is None
    assert described.limits.torque == (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
    assert described.default_gains.kp[3] == 187.0
    assert described.workspace.center == (0.45, 0.13, 0.35)
    assert described.plant.rule == "torque-scaled" and described.plant.stiffness == "medium"
    assert described.uncertainty is None


def test_a_plant_given_number_by_number_needs_no_rule() -> None:
    described = read(with_("plant", EXPLICIT_PLANT))
    assert described.plant.rule is None
    assert described.plant.rotor_inertia == (0.1,) * 6
    assert described.plant.stiffness_presets is not None
    assert described.plant.stiffness_presets.soft == (4000.0,) * 6


@pytest.mark.parametrize(
    "field",
    [
        "name",
        "model",
        "joints",
        "flange",
        "limits",
        "default_gains",
        "torque_interface",
        "workspace",
        "rated_payload",
        "plant",
        "limits.acceleration",
        "torque_interface.adds_gravity",
        "workspace.home",
        "plant.source",
    ],
)
def test_a_missing_field_is_named(field: str) -> None:
    assert refused(with_(field, DELETE)) == f"{field}: missing"


def test_a_plant_number_missing_without_a_rule_is_named() -> None:
    plant = {k: v for k, v in EXPLICIT_PLANT.items() if k != "rotor_inertia"}
    assert refused(with_("plant", plant)) == (
        "plant.rotor_inertia: missing (give it, or rule = 'torque-scaled' to scale it from the "
        "iiwa 14's)"
    )


def test_a_rule_s_numbers_must_be_labelled_assumptions() -> None:
    assert refused(with_("plant.source", "the data sheet")) == (
        "plant.source: the torque-scaled rule's numbers are assumptions: say so (e.g. "
        "'assumption: the iiwa 14's, scaled by torque limit')"
    )
    assert read(with_("plant.source", "Assumption: ours")).plant.source == "Assumption: ours"


def test_an_unknown_field_is_named() -> None:
    assert refused(with_("colour", "orange")).startswith("unknown field 'colour' (known: name,")
    assert refused(with_("limits.jerk", [1.0] * 6)) == "limits: unknown field 'jerk'"


@pytest.mark.parametrize(
    "field",
    [
        "limits.torque",
        "limits.speed",
        "limits.position",
        "limits.acceleration",
        "default_gains.kp",
        "workspace.home",
    ],
)
def test_a_per_joint_list_of_another_length_than_the_joints_is_named(field: str) -> None:
    five = [0.1] * 5
    table = with_(field, five)
    if field == "default_gains.kp":
        table["default_gains"]["kd"] = five  # kp and kd of equal length, both one short
    assert refused(table) == f"{field}: 5 numbers for the 6 joints (j1, j2, j3, j4, j5, j6)"


@pytest.mark.parametrize(
    "field", ["plant.rotor_inertia", "plant.coulomb", "plant.stiffness_presets.stiff"]
)
def test_a_plant_list_of_another_length_than_the_joints_is_named(field: str) -> None:
    table = with_("plant", copy.deepcopy(EXPLICIT_PLANT))
    *parents, last = field.split(".")[1:]
    here = table["plant"]
    for part in parents:
        here = here[part]
    here[last] = [1.0] * 7
    assert refused(table) == f"{field}: 7 numbers for the 6 joints (j1, j2, j3, j4, j5, j6)"


def test_a_joint_count_beyond_the_contract_s_bound_is_refused() -> None:
    assert refused(with_("joints", [f"j{i}" for i in range(33)])) == (
        "joints: 33 items, at most 32 allowed"
    )


@pytest.mark.parametrize("which", ["torque", "speed", "position", "acceleration"])
def test_a_limit_not_positive_is_named(which: str) -> None:
    values = list(VALID["limits"][which])
    values[2] = 0.0
    assert refused(with_(f"limits.{which}", values)) == (
        f"limits.{which}.2: must be more than 0, got 0"
    )


def test_a_limit_beyond_any_arm_is_refused_as_a_unit_slip() -> None:
    speeds = [180.0] * 6  # degrees per second, not radians
    assert refused(with_("limits.speed", speeds)).startswith(
        "limits.speed.0: must be at most 100, got 180 (and "
    )


def test_angles_are_given_as_limits_or_as_ranges() -> None:
    ranges = [[-6.28, 6.28], [-6.28, 6.28], [-0.5, 3.0], [-6.28, 6.28], [-6.28, 6.28], [-1, 1]]
    both = with_("limits.position_range", ranges)
    assert refused(both) == "limits.position: give it, or limits.position_range (not both)"
    neither = with_("limits.position", DELETE)
    assert refused(neither) == "limits.position: give it, or limits.position_range (not both)"
    ranged = with_("limits.position_range", ranges)
    del ranged["limits"]["position"]
    described = read(ranged)
    assert described.limits.ranges()[2] == (-0.5, 3.0)
    assert described.limits.excursion()[2] == 3.0
    ranged["workspace"]["home"] = [-1.57, -1.57, -1.0, -1.57, -1.57, 0.0]
    assert refused(ranged) == (
        "workspace.home: j3 at -1 rad is beyond its position limit -0.5 to 3 rad"
    )
    ranged["limits"]["position_range"][2] = [3.0, -0.5]
    assert refused(ranged) == (
        "limits.position_range.2: lowest 3 rad is not below highest -0.5 rad"
    )
    ranged["limits"]["position_range"] = ranges[:5]
    assert refused(ranged).startswith("limits.position_range: 5 numbers for the 6 joints")


def test_home_beyond_a_position_limit_is_named() -> None:
    home = [0.0, 0.0, 3.5, 0.0, 0.0, 0.0]
    assert refused(with_("workspace.home", home)) == (
        "workspace.home: j3 at 3.5 rad is beyond its position limit ±3.14 rad"
    )


def test_a_centre_outside_the_box_is_named() -> None:
    assert refused(with_("workspace.center", [0.45, 0.13, 0.5])) == (
        "workspace.center: (0.45, 0.13, 0.5) lies outside the box (0.4, 0.0, 0.3)..(0.5, 0.25, 0.4)"
    )


def test_a_box_upside_down_is_named() -> None:
    assert refused(with_("workspace.low", [0.4, 0.3, 0.3])) == (
        "workspace.low: (0.4, 0.3, 0.3) is not below high (0.5, 0.25, 0.4)"
    )


def test_a_model_of_another_format_is_named() -> None:
    assert refused(with_("model", "arm.sdf")) == (
        "model: 'arm.sdf' is neither an MJCF (.xml) nor a URDF (.urdf)"
    )


def test_the_flange_is_a_site_or_a_body() -> None:
    both = {"site": "tool", "body": "wrist"}
    assert refused(with_("flange", both)) == "flange: give a site, or a body (with pos and quat)"
    assert refused(with_("flange", {})) == "flange: give a site, or a body (with pos and quat)"
    offset = {"site": "tool", "pos": [0.0, 0.0, 0.1]}
    assert (
        refused(with_("flange", offset)) == "flange: pos and quat go with a body, not with a site"
    )
    flat = {"body": "wrist", "quat": [0.0, 0.0, 0.0, 0.0]}
    assert refused(with_("flange", flat)) == (
        "flange.quat: a rotation (w x y z) of non-zero length"
    )


def test_joints_named_twice_or_as_a_flexible_joint_s_hinges_are_refused() -> None:
    assert refused(with_("joints", ["j1", "j2", "j3", "j4", "j5", "j1"])) == (
        "joints: a joint named twice"
    )
    spring = ["j1", "j2", "j3", "j4", "j5", "j6_spring"]
    assert refused(with_("joints", spring)) == (
        "joints: 'j6_spring' ends in _motor or _spring, the names of a flexible joint's two "
        "hinges: rename it in the model"
    )


def test_a_joint_name_a_log_cannot_carry_is_refused() -> None:
    joints = ["j1", "j2", "j3", "j4", "j5", "wrist.3"]
    assert refused(with_("joints", joints)).startswith(
        "joints.5: must match the pattern ^[A-Za-z][A-Za-z0-9_/]{0,63}$, got 'wrist.3'"
    )


def test_a_name_that_is_no_plug_in_name_is_refused() -> None:
    assert refused(with_("name", "My Arm")).startswith("name: must match the pattern")


def test_a_rule_the_farm_does_not_know_is_refused() -> None:
    assert refused(with_("plant.rule", "guess")).startswith("plant.rule: must be 'torque-scaled'")


def test_what_is_not_a_description_is_refused_in_one_line() -> None:
    with pytest.raises(BadRobotFile, match=r"^not TOML: "):
        read_robot_file(b"name = ")
    with pytest.raises(BadRobotFile, match=r"^not text$"):
        read_robot_file(b"\xff\xfe")
    with pytest.raises(BadRobotFile, match=rf"more than a robot description's {MAX_FILE_BYTES}$"):
        read_robot_file(b"#" * (MAX_FILE_BYTES + 1))
    with pytest.raises(BadRobotFile, match=r"^nesting deeper than 32 levels$"):
        read_robot_file(b"x = " + b"[" * 40 + b"]" * 40)
