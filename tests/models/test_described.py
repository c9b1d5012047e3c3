"""A user's own arm from a robot description: a 6-joint arm from an MJCF (the vendored UR5e's,
copied with other names) and a 7-joint one from a URDF (the iiwa's, models/urdf.py), each through
the robot kit; what needs the model refused in one line naming the field; the arm registered and
found by its name, on the command line as in the process."""

import math
import re
import subprocess
import sys
from collections.abc import Iterator
from importlib.resources import files
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import click
import mujoco
import numpy as np
import pytest
import tomli_w
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from gainfarm import plugins
from gainfarm.analytic.tuning.plants import ranges
from gainfarm.cli import options
from gainfarm.models import described, robot_of, ur5e
from gainfarm.models.described import register_file, robot_from_file, source_of
from gainfarm.models.iiwa14 import RIGID_MJCF, VISCOUS_FRICTION
from gainfarm.models.urdf import urdf
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.robot import (
    DEFAULT_ROTOR_INERTIA,
    STIFFNESS_PRESETS,
    TORQUE_LIMITS,
    PlantSpec,
)
from gainfarm.schemas.robot_file import BadRobotFile
from gainfarm.testing.robots import check_robot
from tests.helpers import analytic

# The UR5e's joints under other names: the arm is "ours", not the shipped one.
RENAMED = {
    "shoulder_pan_joint": "base_turn",
    "shoulder_lift_joint": "shoulder",
    "elbow_joint": "elbow",
    "wrist_1_joint": "wrist_a",
    "wrist_2_joint": "wrist_b",
    "wrist_3_joint": "wrist_c",
}
JOINTS = list(RENAMED.values())


def ur5e_description(**changes: Any) -> dict[str, Any]:
    """A description of the vendored UR5e copied as arm6.xml, its numbers models/ur5e.py's."""
    table: dict[str, Any] = {
        "name": "my_arm",
        "model": "arm6.xml",
        "joints": JOINTS,
        "rated_payload": ur5e.RATED_PAYLOAD,
        "flange": {
            "body": "wrist_3_link",
            "pos": list(ur5e.ROBOT.flange_pos),
            "quat": list(ur5e.ROBOT.flange_quat),
        },
        "limits": {
            "torque": list(ur5e.TORQUE_LIMITS),
            "speed": list(ur5e.SPEED_LIMITS),
            "position": list(ur5e.POSITION_LIMITS),
            "acceleration": list(ur5e.ACCELERATION_LIMITS),
        },
        "default_gains": {
            "kp": list(ur5e.DEFAULT_GAINS.kp),
            "kd": list(ur5e.DEFAULT_GAINS.kd),
        },
        "torque_interface": {
            "name": "direct torque",
            "adds_gravity": True,
            "description": "the controller adds its gravity model to the command",
        },
        "workspace": {
            "home": list(ur5e.WORKSPACE.home),
            "center": list(ur5e.WORKSPACE.center),
            "low": list(ur5e.WORKSPACE.low),
            "high": list(ur5e.WORKSPACE.high),
        },
        "plant": {"rule": "torque-scaled", "source": "assumption: the iiwa 14's, scaled"},
    }
    table.update(changes)
    return table


def write_arm6(folder: Path, xml: str | None = None, **changes: Any) -> Path:
    """arm6.xml (the vendored UR5e, its joints renamed) and my_arm.toml beside it."""
    if xml is None:
        xml = files("gainfarm.models").joinpath("menagerie/ur5e/ur5e.xml").read_text()
        for old, new in RENAMED.items():
            xml = xml.replace(f'"{old}"', f'"{new}"')
    (folder / "arm6.xml").write_text(xml)
    path = folder / "my_arm.toml"
    path.write_text(tomli_w.dumps(ur5e_description(**changes)))
    return path


def iiwa_urdf() -> str:
    """models/urdf.py's URDF of the iiwa 14 with its links' inertials, as a maker's URDF has
    them (models/urdf.py leaves them out: a drawing needs none), from the MJCF's open set."""
    model = mujoco.MjModel.from_xml_string(RIGID_MJCF.read_text())
    bodies = {model.body(i).name: i for i in range(1, model.nbody)}
    root = ElementTree.fromstring(urdf())
    for link in root.iter("link"):
        body = bodies.get(link.get("name", ""))
        if body is None or link.find("inertial") is not None:
            continue  # the flange (a frame, no mass), or a link that has its inertial
        inertial = ElementTree.SubElement(link, "inertial")
        w, x, y, z = model.body_iquat[body]
        rpy = Rotation.from_quat([x, y, z, w]).as_euler("xyz")
        ElementTree.SubElement(
            inertial,
            "origin",
            xyz=" ".join(map(repr, model.body_ipos[body].tolist())),
            rpy=" ".join(map(repr, rpy.tolist())),
        )
        ElementTree.SubElement(inertial, "mass", value=repr(float(model.body_mass[body])))
        ixx, iyy, izz = model.body_inertia[body].tolist()
        ElementTree.SubElement(
            inertial,
            "inertia",
            ixx=repr(ixx),
            iyy=repr(iyy),
            izz=repr(izz),
            ixy="0",
            ixz="0",
            iyz="0",
        )
    return ElementTree.tostring(root, encoding="unicode")


def write_iiwa_urdf(folder: Path) -> Path:
    (folder / "iiwa.urdf").write_text(iiwa_urdf())
    robot = robot_of("iiwa14")
    table = {
        "name": "urdf_arm",
        "model": "iiwa.urdf",
        "joints": list(robot.joint_names),
        "rated_payload": robot.rated_payload,
        "flange": {"body": "flange"},  # the URDF's frame, fused into link7 by MuJoCo
        "limits": {
            "torque": list(robot.limits.torque),
            "speed": list(robot.limits.speed),
            "position": list(robot.limits.position),
            "acceleration": list(robot.limits.acceleration),
        },
        "default_gains": {"kp": list(robot.default_gains.kp), "kd": list(robot.default_gains.kd)},
        "torque_interface": {
            "name": robot.torque_interface.name,
            "adds_gravity": robot.torque_interface.adds_gravity,
            "description": robot.torque_interface.description,
        },
        "workspace": {
            "home": list(robot.workspace.home),
            "center": list(robot.workspace.center),
            "low": list(robot.workspace.low),
            "high": list(robot.workspace.high),
        },
        "plant": {
            "source": "the iiwa 14's own (models/iiwa14.py)",
            "stiffness": robot.plant_defaults.stiffness,
            "stiffness_presets": {
                k: list(v) for k, v in robot.plant_defaults.stiffness_presets.items()
            },
            "spring_damping": list(robot.plant_defaults.spring_damping),
            "rotor_inertia": list(robot.plant_defaults.rotor_inertia),
            "viscous": list(robot.plant_defaults.viscous),
            "coulomb": list(robot.plant_defaults.coulomb),
        },
    }
    path = folder / "urdf_arm.toml"
    path.write_text(tomli_w.dumps(table))
    return path


@pytest.fixture(autouse=True)
def forgotten() -> Iterator[None]:
    """Every arm a test registers is forgotten after it."""
    yield
    for name in ("my_arm", "urdf_arm", "other_arm"):
        described.forget(name)


def refused(path: Path) -> str:
    with pytest.raises(BadRobotFile) as error:
        robot_from_file(path)
    message = str(error.value)
    assert "\n" not in message
    return message


# --- the arms through the kit ---------------------------------------------------------------------


def test_a_six_joint_arm_from_an_mjcf_passes_the_robot_kit(tmp_path: Path) -> None:
    name = register_file(write_arm6(tmp_path))
    assert name == "my_arm" and source_of(name) == (tmp_path / "my_arm.toml").resolve()
    robot = robot_of(name)
    assert robot.joint_names == tuple(JOINTS)
    check_robot(robot)


def test_a_seven_joint_arm_from_a_urdf_passes_the_robot_kit(tmp_path: Path) -> None:
    name = register_file(write_iiwa_urdf(tmp_path))
    robot = robot_of(name)
    assert robot.joint_names == robot_of("iiwa14").joint_names
    check_robot(robot)


def test_the_urdf_arm_is_the_iiwa_it_was_written_from(tmp_path: Path) -> None:
    """Same masses, same flange at home, and the URDF's effort limits not clipping the motors a
    second time (MuJoCo reads <limit effort> as the hinge's actuator force range)."""
    robot = robot_of(register_file(write_iiwa_urdf(tmp_path)))
    iiwa = robot_of("iiwa14")
    ours = robot.build(PlantSpec(robot=robot.name, joints="rigid", inertials="menagerie"))
    theirs = iiwa.build(PlantSpec(joints="rigid", inertials="open"))
    links = [f"link{i}" for i in range(1, 8)]
    assert [ours.body(link).mass[0] for link in links] == pytest.approx(
        [theirs.body(link).mass[0] for link in links], rel=1e-5
    )
    assert not ours.jnt_actfrclimited.any()
    assert flange_at_home(robot) == pytest.approx(flange_at_home(iiwa), abs=1e-5)


def test_the_mjcf_arm_keeps_the_described_numbers_and_the_ur5e_s_flange(tmp_path: Path) -> None:
    robot = robot_of(register_file(write_arm6(tmp_path)))
    assert robot.limits.torque == ur5e.TORQUE_LIMITS
    assert robot.default_gains == ur5e.DEFAULT_GAINS
    assert robot.workspace == ur5e.WORKSPACE
    assert robot.rated_payload == ur5e.RATED_PAYLOAD
    assert robot.torque_interface.adds_gravity
    assert flange_at_home(robot) == pytest.approx(flange_at_home(ur5e.ROBOT), abs=1e-5)


def flange_at_home(robot: Any) -> list[float]:
    """The flange's position and orientation (9 numbers of its matrix) at home, rigid."""
    model = robot.build(PlantSpec(robot=robot.name, joints="rigid", inertials="menagerie"))
    data = mujoco.MjData(model)
    data.qpos[:] = robot.workspace.home
    mujoco.mj_kinematics(model, data)
    site = data.site(robot.flange)
    return [*site.xpos.tolist(), *site.xmat.tolist()]


def test_asymmetric_position_ranges_are_the_hinges(tmp_path: Path) -> None:
    limits = dict(ur5e_description()["limits"])
    del limits["position"]
    ranges = [[-6.0, 6.0], [-6.0, 6.0], [-2.5, 3.0], [-6.0, 6.0], [-6.0, 6.0], [-6.0, 6.0]]
    robot = robot_of(
        register_file(write_arm6(tmp_path, limits=limits | {"position_range": ranges}))
    )
    model = robot.build(PlantSpec(robot=robot.name, joints="rigid"))
    assert model.joint("elbow").range.tolist() == [-2.5, 3.0]
    assert robot.limits.position[2] == 3.0  # the largest excursion either way
    assert robot.limits.ranges[2] == (-2.5, 3.0)


# --- the plant numbers and ranges the description leaves out --------------------------------------


def test_the_torque_scaled_rule_takes_the_iiwa_s_nearest_joint_by_torque(tmp_path: Path) -> None:
    robot = robot_from_file(write_arm6(tmp_path))
    defaults = robot.plant_defaults
    # 150 N·m is nearest the iiwa's A3 (176 N·m); 28 N·m its A7 (40 N·m, of A6's and A7's the
    # one nearer the flange).
    big, small = 150.0 / TORQUE_LIMITS[2], 28.0 / TORQUE_LIMITS[6]
    medium = STIFFNESS_PRESETS["medium"]
    assert defaults.stiffness_presets["medium"][0] == pytest.approx(medium[2] * big, rel=1e-3)
    assert defaults.stiffness_presets["medium"][5] == pytest.approx(medium[6] * small, rel=1e-3)
    assert defaults.rotor_inertia[0] == pytest.approx(DEFAULT_ROTOR_INERTIA[2] * big, rel=1e-3)
    assert defaults.viscous[5] == pytest.approx(VISCOUS_FRICTION[6] * small, rel=1e-3)
    assert defaults.coulomb == (2.25, 2.25, 2.25, 0.42, 0.42, 0.42)  # 1.5 % of the limit
    assert defaults.stiffness == "medium"


def test_plant_numbers_given_are_taken_as_given(tmp_path: Path) -> None:
    plant = {
        "source": "measured",
        "stiffness": "soft",
        "stiffness_presets": {"soft": [3000.0] * 6, "medium": [9000.0] * 6, "stiff": [2e4] * 6},
        "spring_damping": [7.0] * 6,
        "rotor_inertia": [0.2] * 6,
        "viscous": [0.25] * 6,
        "coulomb": [1.0] * 6,
    }
    defaults = robot_from_file(write_arm6(tmp_path, plant=plant)).plant_defaults
    assert defaults.stiffness == "soft"
    assert defaults.stiffness_presets["soft"] == (3000.0,) * 6
    assert defaults.rotor_inertia == (0.2,) * 6 and defaults.coulomb == (1.0,) * 6


def test_the_default_ranges_are_the_iiwa_s_with_the_payload_scaled(tmp_path: Path) -> None:
    robot = robot_from_file(write_arm6(tmp_path))
    table = ranges(robot.uncertainty.read_text())  # the analytic side's reader accepts them
    iiwa = ranges()
    assert table["payload"].high == pytest.approx(3.0 * ur5e.RATED_PAYLOAD / 14.0, rel=1e-3)
    same = ("field", "low", "high", "draw")
    assert [getattr(table["mass_scale"], k) for k in same] == [
        getattr(iiwa["mass_scale"], k) for k in same
    ]
    assert table["mass_scale"].why.startswith("the iiwa 14's range, taken for my_arm: ")
    assert set(table) == set(iiwa)


def test_a_ranges_file_of_its_own_is_the_arm_s(tmp_path: Path) -> None:
    own = files("gainfarm.models").joinpath("uncertainty_ur5e.toml").read_text()
    (tmp_path / "ranges.toml").write_text(own)
    robot = robot_from_file(write_arm6(tmp_path, uncertainty="ranges.toml"))
    assert robot.uncertainty.read_text() == own


def test_a_ranges_file_missing_or_not_toml_is_named(tmp_path: Path) -> None:
    path = write_arm6(tmp_path, uncertainty="ranges.toml")
    assert refused(path) == f"uncertainty: no file '{tmp_path / 'ranges.toml'}'"
    (tmp_path / "ranges.toml").write_text("payload = 3\n")
    assert refused(path) == "uncertainty: 'payload' is not a table of a range"


# --- what needs the model, refused naming the field -----------------------------------------------


def test_a_joint_the_model_lacks_is_named(tmp_path: Path) -> None:
    joints = [*JOINTS[:5], "wrist_z"]
    assert refused(write_arm6(tmp_path, joints=joints)) == (
        "joints: the model has no joint 'wrist_z' (it has: base_turn, elbow, shoulder, wrist_a, "
        "wrist_b, wrist_c)"
    )


def test_joints_out_of_order_are_named(tmp_path: Path) -> None:
    joints = [JOINTS[1], JOINTS[0], *JOINTS[2:]]
    assert refused(write_arm6(tmp_path, joints=joints)) == (
        "joints: 'base_turn' does not move with 'shoulder': list the joints base to flange, one "
        "chain"
    )


def test_a_joint_that_is_no_hinge_is_named(tmp_path: Path) -> None:
    xml = write_arm6(tmp_path).parent.joinpath("arm6.xml").read_text()
    slid = xml.replace('name="elbow"', 'name="elbow" type="slide"', 1)
    assert (
        refused(write_arm6(tmp_path, xml=slid)) == "joints: 'elbow' is a slide joint, not a hinge"
    )


def test_a_joint_the_description_leaves_out_is_welded(tmp_path: Path) -> None:
    """A gripper's finger: its joint goes, the body stays on the wrist."""
    xml = write_arm6(tmp_path).parent.joinpath("arm6.xml").read_text()
    finger = (
        '<body name="finger" pos="0 0.12 0"><joint name="finger_slide" type="slide"/>'
        '<inertial pos="0 0 0" mass="0.2" diaginertia="1e-4 1e-4 1e-4"/></body>'
    )
    xml = re.sub(r'(<body name="wrist_3_link"[^>]*>)', r"\1" + finger, xml, count=1)
    robot = robot_of(register_file(write_arm6(tmp_path, xml=xml)))
    model = robot.build(PlantSpec(robot=robot.name, joints="rigid"))
    assert model.nq == 6 and model.body("finger").mass[0] == pytest.approx(0.2)


def test_mujoco_s_own_gravity_compensation_of_a_body_is_dropped(tmp_path: Path) -> None:
    xml = write_arm6(tmp_path).parent.joinpath("arm6.xml").read_text()
    xml = xml.replace('<body name="forearm_link"', '<body name="forearm_link" gravcomp="1"', 1)
    robot = robot_of(register_file(write_arm6(tmp_path, xml=xml)))
    assert not robot.build(PlantSpec(robot=robot.name)).body_gravcomp.any()


def test_a_flange_site_of_the_model_is_the_flange(tmp_path: Path) -> None:
    """The same flange as the body and offset give, written into the model as a site."""
    body_form = flange_at_home(robot_of(register_file(write_arm6(tmp_path))))
    described.forget("my_arm")
    xml = write_arm6(tmp_path).parent.joinpath("arm6.xml").read_text()
    pos, quat = ur5e.ROBOT.flange_pos, ur5e.ROBOT.flange_quat
    site = f'<site name="tool0" pos="{" ".join(map(str, pos))}" quat="{" ".join(map(str, quat))}"/>'
    xml = re.sub(r'(<body name="wrist_3_link"[^>]*>)', r"\1" + site, xml, count=1)
    robot = robot_of(register_file(write_arm6(tmp_path, xml=xml, flange={"site": "tool0"})))
    assert robot.flange == "tool0"
    assert flange_at_home(robot) == pytest.approx(body_form, abs=1e-9)


def test_a_flange_the_model_lacks_or_that_does_not_move_with_the_last_joint_is_named(
    tmp_path: Path,
) -> None:
    path = write_arm6(tmp_path, flange={"site": "tool0"})
    assert refused(path) == "flange.site: the model has no site 'tool0'"
    path = write_arm6(tmp_path, flange={"body": "tool0"})
    assert refused(path) == "flange.body: the model has no body 'tool0'"
    path = write_arm6(tmp_path, flange={"body": "forearm_link"})
    assert refused(path) == (
        "flange.body: on body 'forearm_link', which the last joint 'wrist_c' does not move"
    )


def test_a_model_that_is_missing_or_does_not_compile_is_named(tmp_path: Path) -> None:
    path = write_arm6(tmp_path, model="nowhere.xml")
    assert refused(path) == f"model: no file '{tmp_path / 'nowhere.xml'}'"
    path = write_arm6(tmp_path, xml="<mujoco><worldbody><body></mujoco>")
    assert refused(path).startswith("model: ")
    xml = write_arm6(tmp_path).parent.joinpath("arm6.xml").read_text()
    massless = xml.replace(
        '<inertial mass="2.275" pos="0 0 0.196" diaginertia="0.0311796 0.0311796 0.004095"/>',
        '<inertial mass="0" pos="0 0 0.196" diaginertia="0 0 0"/>',
    )
    assert massless != xml
    assert refused(write_arm6(tmp_path, xml=massless)) == (
        "model: mass and inertia of moving bodies must be larger than mjMINVAL"
    )


def test_a_workspace_out_of_reach_is_named(tmp_path: Path) -> None:
    far = ur5e_description()["workspace"] | {"center": [1.5, 0.1, 0.35], "high": [1.6, 0.25, 0.4]}
    assert re.fullmatch(
        r"workspace\.center \(1\.5, 0\.1, 0\.35\) is out of the arm's reach with the flange "
        r"pointing down \(\d\.\d{3} m from the first joint, it reaches \d\.\d{3} m\)",
        refused(write_arm6(tmp_path, workspace=far)),
    )
    corner = ur5e_description()["workspace"] | {"high": [1.5, 0.25, 0.4]}
    assert re.match(
        r"workspace\.low/high: corner \(1\.5, -?[\d.]+, [\d.]+\) is out of the arm's reach",
        refused(write_arm6(tmp_path, workspace=corner)),
    )


def test_springs_the_physics_step_cannot_integrate_are_named(tmp_path: Path) -> None:
    plant = {"rule": "torque-scaled", "source": "assumption", "stiffness": "stiff"}
    plant["stiffness_presets"] = {"soft": [1e3] * 6, "medium": [1e4] * 6, "stiff": [5e6] * 6}
    message = refused(write_arm6(tmp_path, plant=plant))
    assert message.startswith("plant.stiffness: the 'stiff' preset: substeps=2 is too few for ")
    assert message.endswith("(a softer preset, or softer springs)")


def test_a_name_another_robot_has_is_refused(tmp_path: Path) -> None:
    assert refused(write_arm6(tmp_path, name="iiwa14")) == (
        "name: 'iiwa14' is a robot installed here; choose another"
    )
    register_file(write_arm6(tmp_path))
    other = tmp_path / "other"
    other.mkdir()
    assert refused(write_arm6(other)) == (
        f"name: 'my_arm' is the robot described in {(tmp_path / 'my_arm.toml').resolve()}"
    )


def test_a_meshed_model_builds_from_anywhere(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The model's meshes are found beside it, wherever the process runs."""
    assets = tmp_path / "assets"
    assets.mkdir()
    (assets / "box.obj").write_text(
        "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    )
    xml = write_arm6(tmp_path).parent.joinpath("arm6.xml").read_text()
    xml = xml.replace("<compiler", '<compiler meshdir="assets"', 1)
    xml = xml.replace("<default>", '<asset><mesh name="box" file="box.obj"/></asset><default>', 1)
    xml = re.sub(
        r'(<body name="wrist_3_link"[^>]*>)',
        r'\1<geom type="mesh" mesh="box" mass="0"/>',
        xml,
        count=1,
    )
    path = write_arm6(tmp_path, xml=xml)
    monkeypatch.chdir(tmp_path.parent)
    robot = robot_of(register_file(path))
    assert robot.build(PlantSpec(robot=robot.name)).nmesh == 1


# --- the documented example ----------------------------------------------------------------------

ROOT = Path(__file__).parents[2]
EXAMPLE = ROOT / "docs/examples/my_arm.toml"


def test_the_documented_example_describes_an_arm_that_passes_the_kit() -> None:
    robot = robot_of(register_file(EXAMPLE))
    assert robot.name == "my_arm" and len(robot.joint_names) == 6
    assert robot.plant_defaults.rotor_inertia == (0.1,) * 6  # given, the rest by the rule
    check_robot(robot)


def test_docs_robot_md_shows_the_example_whole() -> None:
    doc = (ROOT / "docs/robot.md").read_text()
    section = doc[doc.index("### Your own arm") :]
    block = section[section.index("```toml\n") + len("```toml\n") :]
    assert block[: block.index("```")] == EXAMPLE.read_text()


# --- registered in the process --------------------------------------------------------------------


def test_a_failing_description_leaves_nothing_registered(tmp_path: Path) -> None:
    path = write_arm6(tmp_path, flange={"site": "tool0"})
    with pytest.raises(BadRobotFile):
        register_file(path)
    assert "my_arm" not in plugins.names(plugins.ROBOTS)
    assert source_of("my_arm") is None and source_of("iiwa14") is None


def test_the_same_file_registers_again_and_a_changed_one_replaces_it(tmp_path: Path) -> None:
    path = write_arm6(tmp_path)
    register_file(path)
    kp = [2 * v for v in ur5e.DEFAULT_GAINS.kp]
    path.write_text(
        tomli_w.dumps(ur5e_description(default_gains={"kp": kp, "kd": list(ur5e.DEFAULT_GAINS.kd)}))
    )
    assert register_file(path) == "my_arm"
    assert robot_of("my_arm").default_gains.kp == tuple(kp)


@click.command()
@options.robot()
def joints_of(robot: str) -> None:
    """A command taking --robot, as gainfarm's do: prints the arm's joints."""
    click.echo(" ".join(robot_of(robot).joint_names))


def test_robot_file_on_the_command_line_is_registered_or_refused_in_one_line(
    tmp_path: Path,
) -> None:
    path = write_arm6(tmp_path)
    ran = CliRunner().invoke(joints_of, ["--robot", str(path)])
    assert (ran.exit_code, ran.output) == (0, " ".join(JOINTS) + "\n")
    described.forget("my_arm")
    bad = write_arm6(tmp_path, joints=JOINTS[:5])
    ran = CliRunner().invoke(joints_of, ["--robot", str(bad)])
    assert ran.exit_code == 2
    assert ran.output == (
        f"Error: --robot: {bad}: limits.torque: 6 numbers for the 5 joints "
        "(base_turn, shoulder, elbow, wrist_a, wrist_b)\n"
    )
    assert "my_arm" not in plugins.names(plugins.ROBOTS)
    missing = tmp_path / "missing.toml"
    ran = CliRunner().invoke(joints_of, ["--robot", str(missing)])
    assert (ran.exit_code, ran.output) == (
        2,
        f"Error: --robot: {missing}: cannot read it: No such file or directory\n",
    )


def test_the_rule_s_numbers_are_finite_and_positive(tmp_path: Path) -> None:
    defaults = robot_from_file(write_arm6(tmp_path)).plant_defaults
    numbers = [
        *defaults.spring_damping,
        *defaults.rotor_inertia,
        *defaults.viscous,
        *(v for preset in defaults.stiffness_presets.values() for v in preset),
    ]
    assert all(math.isfinite(v) and v > 0 for v in numbers)
    assert np.all(np.diff(defaults.stiffness_presets["soft"]) <= 0)  # big joints the stiffest


# --- the command lines, as a user runs them -------------------------------------------------------

WORKER = [sys.executable, "-c", "from gainfarm.worker.cli import main; main()"]


def worker(*arguments: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*WORKER, *arguments], cwd=cwd, capture_output=True, text=True, timeout=300
    )


@pytest.mark.slow
def test_worker_episode_runs_a_described_arm_and_logs_its_joint_names(tmp_path: Path) -> None:
    write_arm6(tmp_path)
    ran = worker(
        *("episode", "--robot", "my_arm.toml", "--duration", "4", "--out", "ep.mcap", "--json"),
        cwd=tmp_path,
    )
    assert ran.returncode == 0, ran.stderr
    log = read_episode(tmp_path / "ep.mcap")
    assert log.metadata.joint_names == tuple(JOINTS)
    assert log.metadata.spec.plant.robot == "my_arm"
    assert log.metadata.spec.gains == ur5e.DEFAULT_GAINS  # the description's default gains
    assert log.q.shape[1] == 6 and not log.metadata.diverged


def test_worker_episode_refuses_a_bad_description_in_one_line_and_writes_nothing(
    tmp_path: Path,
) -> None:
    home = [-1.57, -1.57, 3.5, -1.57, -1.57, 0.0]
    workspace = ur5e_description()["workspace"] | {"home": home}
    write_arm6(tmp_path, workspace=workspace)
    ran = worker("episode", "--robot", "my_arm.toml", "--out", "ep.mcap", cwd=tmp_path)
    assert ran.returncode == 2
    assert ran.stderr.splitlines() == [
        "worker: error: --robot: my_arm.toml: workspace.home: elbow at 3.5 rad is beyond its "
        "position limit ±3.14159 rad"
    ]
    assert not (tmp_path / "ep.mcap").exists()


@pytest.mark.slow
def test_analytic_start_tunes_a_described_arm_on_a_local_farm(tmp_path: Path) -> None:
    """The local farm's workers are handed the description (source_of) and run its jobs."""
    write_arm6(tmp_path)
    run = analytic(
        "start",
        *("--robot", "my_arm.toml", "--pop", "4", "--generations", "1"),
        *("--trajectory", "fourier", "--duration", "0.5", "--check-plants", "2"),
        *("--workers", "1", "--out", "run"),
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr
    config = (tmp_path / "run/config.json").read_text()
    assert '"robot":"my_arm"' in config.replace(" ", "")
    logs = sorted((tmp_path / "run/episodes").glob("*.mcap"))
    assert logs, "no episode logs"
    for path in logs:
        log = read_episode(path)
        assert log.metadata.joint_names == tuple(JOINTS)
        assert log.metadata.spec.plant.robot == "my_arm"


def test_analytic_start_refuses_a_bad_description_in_one_line(tmp_path: Path) -> None:
    write_arm6(tmp_path, joints=JOINTS[:5])
    run = analytic("start", "--robot", "my_arm.toml", "--out", "run", cwd=tmp_path)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [
        "analytic: error: --robot: my_arm.toml: limits.torque: 6 numbers for the 5 joints "
        "(base_turn, shoulder, elbow, wrist_a, wrist_b)"
    ]
    assert not (tmp_path / "run").exists()
