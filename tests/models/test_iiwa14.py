import subprocess
import sys

import mujoco
import numpy as np
import pytest

from gainfarm.models import (
    CAD_INERTIALS,
    READY_POSTURE,
    RIGID_MJCF,
    UPRIGHT_POSTURE,
    build_spec,
    compile_model,
    elastic_modes,
    min_substeps,
    resolve,
    step_ratios,
)
from gainfarm.schemas import TORQUE_LIMITS, PlantSpec
from gainfarm.schemas.robot import IDEAL_PLANT, STIFFNESS_PRESETS, Friction

HOME = np.array([0.0, 0.785398, 0.0, -1.5708, 0.0, 0.0, 0.0])
LINKS = [f"link{i}" for i in range(1, 8)]
CAD_LINK_MASSES = (4.0, 3.95, 3.18, 2.74, 1.69, 1.8, 0.31)  # link 1: iiwa_stack's (assumption)
# The physics steps per control tick each preset needs, per inertial set (models/README.md).
PRESET_SUBSTEPS = {
    ("soft", "open"): 2,
    ("soft", "cad"): 2,
    ("medium", "open"): 2,
    ("medium", "cad"): 2,
    ("stiff", "open"): 5,
    ("stiff", "cad"): 7,
    ("soft", "menagerie"): 2,
    ("medium", "menagerie"): 2,
    ("stiff", "menagerie"): 5,
}


def _hinges(model: mujoco.MjModel, suffix: str) -> np.ndarray:
    return np.array([model.joint(f"A{i}{suffix}").dofadr[0] for i in range(1, 8)])


def test_open_inertials_match_the_published_numbers():
    model = compile_model(PlantSpec(joints="rigid", inertials="open"))
    data = mujoco.MjData(model)
    assert (model.nq, model.nu) == (7, 7)
    # Total mass of the seven links and the base, from the open descriptions' table.
    assert model.body_mass.sum() == pytest.approx(30.61, abs=0.01)
    np.testing.assert_allclose(model.actuator_ctrlrange[:, 1], TORQUE_LIMITS)
    data.qpos[:] = HOME
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.site("flange").xpos, [0.669, 0.0, 0.285], atol=1e-3)
    # Gravity torques at home: the reference quotes about 57 N·m on A2 and 17 N·m on A4.
    assert abs(data.qfrc_bias[1]) == pytest.approx(57, abs=1)
    assert abs(data.qfrc_bias[3]) == pytest.approx(17, abs=1)


def test_open_inertials_compile_to_the_hand_written_file_unchanged():
    # The ideal plant must reproduce the first wave's episodes: its links are the XML's, bit for
    # bit, and without friction its motor hinges carry no damping.
    written = mujoco.MjModel.from_xml_string(RIGID_MJCF.read_text())
    for spec in (IDEAL_PLANT, PlantSpec(joints="rigid", inertials="open", friction=None)):
        model = compile_model(spec)
        for field in ("body_mass", "body_ipos", "body_iquat", "body_inertia", "body_pos"):
            np.testing.assert_array_equal(getattr(model, field), getattr(written, field))
        assert not model.dof_damping[_hinges(model, "_motor" if model.nq == 14 else "")].any()


def test_cad_inertials_carry_the_cad_masses_and_menageries_axes():
    open_ = compile_model(PlantSpec(joints="rigid", inertials="open"))
    cad = compile_model(PlantSpec(joints="rigid", inertials="cad"))
    masses = [cad.body(link).mass[0] for link in LINKS]
    np.testing.assert_allclose(masses, CAD_LINK_MASSES)
    assert cad.body_mass.sum() == pytest.approx(22.67, abs=0.01)  # with the 5 kg base
    assert tuple(mass for mass, _ in CAD_INERTIALS.values()) == CAD_LINK_MASSES
    for link in LINKS:
        ratio = cad.body(link).mass[0] / open_.body(link).mass[0]
        np.testing.assert_allclose(cad.body(link).inertia, ratio * open_.body(link).inertia)
        np.testing.assert_array_equal(cad.body(link).ipos, open_.body(link).ipos)
    half = np.sqrt(0.5)
    np.testing.assert_allclose(cad.body("link2").iquat, [0, 0, half, half])
    for link in ("link4", "link6"):
        np.testing.assert_allclose(cad.body(link).iquat, [half, half, 0, 0])
    # Each re-oriented link's smallest moment is about its long axis, y (the next joint's
    # offset), as in Menagerie: in the open set it was about z, the joint axis.
    for link in ("link2", "link4", "link6"):
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, cad.body(link).iquat)
        rotation = rotation.reshape(3, 3)
        inertia = rotation @ np.diag(cad.body(link).inertia) @ rotation.T
        assert np.argmin(np.diag(inertia)) == 1
    # The kinematics do not change with the inertials.
    np.testing.assert_array_equal(cad.body_pos, open_.body_pos)


def test_viscous_friction_lands_as_motor_hinge_damping():
    friction = Friction(viscous=(0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1))
    spec = PlantSpec(friction=friction)
    flexible = compile_model(spec)
    motor_damping = flexible.dof_damping[_hinges(flexible, "_motor")]
    np.testing.assert_array_equal(motor_damping, friction.viscous)
    np.testing.assert_array_equal(
        flexible.dof_damping[_hinges(flexible, "_spring")], resolve(spec).spring_damping
    )
    rigid = compile_model(PlantSpec(joints="rigid", friction=friction))
    np.testing.assert_array_equal(rigid.dof_damping, friction.viscous)
    # Never as frictionloss: it costs half again the physics time; the tick loop applies Coulomb.
    assert not flexible.dof_frictionloss.any()
    assert not compile_model(PlantSpec(friction=None)).dof_damping[0::2].any()


def test_flexible_variant_is_generated_from_the_same_chain():
    spec = PlantSpec(stiffness=(1234.0,) * 7)
    rigid = compile_model(PlantSpec(joints="rigid"))
    flexible = compile_model(spec)
    assert flexible.nq == 14
    names = [flexible.joint(j).name for j in range(flexible.njnt)]
    assert names[:4] == ["A1_motor", "A1_spring", "A2_motor", "A2_spring"]
    np.testing.assert_allclose(flexible.body_mass, rigid.body_mass)
    np.testing.assert_allclose(flexible.body_pos, rigid.body_pos)
    np.testing.assert_allclose(flexible.jnt_stiffness[1::2], 1234.0)
    np.testing.assert_allclose(flexible.dof_armature[0::2], resolve(spec).rotor_inertia)
    # The motors drive the motor-side hinges.
    assert [flexible.joint(j).name for j in flexible.actuator_trnid[:, 0]] == [
        f"A{i}_motor" for i in range(1, 8)
    ]


def test_control_period_is_split_into_the_requested_substeps():
    assert compile_model(PlantSpec(substeps=4)).opt.timestep == pytest.approx(0.0005)


def test_exported_mjcf_compiles_to_the_same_model():
    xml = build_spec(PlantSpec()).to_xml()
    reloaded = mujoco.MjModel.from_xml_string(xml)
    assert reloaded.nq == 14
    model = compile_model(PlantSpec())
    # MJCF carries 6 significant digits: the CAD set's scaled inertias round in the last one.
    for field in ("jnt_stiffness", "dof_damping", "body_mass", "body_inertia", "body_iquat"):
        np.testing.assert_allclose(getattr(reloaded, field), getattr(model, field), rtol=1e-5)


def test_elastic_modes_of_the_first_waves_plant():
    # The reference: with the first wave's values the modes at the ready posture sit at about
    # 19-60 Hz, and A7's, the link-7 disc on its spring, far above them.
    modes = elastic_modes(IDEAL_PLANT)
    assert modes[0] == pytest.approx(19, abs=0.5)
    assert modes[4] == pytest.approx(60, abs=1)
    assert modes[-1] == pytest.approx(229, abs=1)
    # The CAD set's lighter wrist puts A7's mode near 446 Hz.
    assert elastic_modes(PlantSpec(inertials="cad"))[-1] == pytest.approx(446, abs=1)


@pytest.mark.parametrize(("preset", "inertials"), sorted(PRESET_SUBSTEPS))
def test_each_preset_holds_the_arm_still_at_its_documented_substeps(preset, inertials):
    substeps = PRESET_SUBSTEPS[preset, inertials]
    spec = PlantSpec(inertials=inertials, stiffness=STIFFNESS_PRESETS[preset], substeps=substeps)
    assert min_substeps(spec) == substeps
    compile_model(spec)  # the guard accepts it
    for posture in (READY_POSTURE, UPRIGHT_POSTURE):
        error, speed = _hold(spec, np.array(posture))
        assert error < 1e-4  # rad: the link angles stay where they were
        assert speed < 5e-3  # rad/s, every hinge: the springs wound up and settled


def _hold(spec: PlantSpec, posture: np.ndarray, seconds: float = 2.0) -> tuple[float, float]:
    """Start with the springs relaxed at `posture` and hold it for `seconds` with the motors'
    gravity-holding torque and a PD on the motor angle that keeps the springs wound up."""
    model = build_spec(spec).compile()
    data = mujoco.MjData(model)
    motor, spring = _hinges(model, "_motor"), _hinges(model, "_spring")
    data.qpos[motor] = posture
    mujoco.mj_forward(model, data)
    gravity = data.qfrc_bias[motor].copy()
    wound = posture + gravity / np.asarray(spec.stiffness)  # the motor angles at equilibrium
    kp = np.array([2000.0, 2000.0, 1200.0, 1200.0, 400.0, 200.0, 100.0])
    kd = np.array([20.0, 20.0, 15.0, 15.0, 4.0, 2.0, 1.0])
    for _ in range(round(seconds / 0.002)):
        data.ctrl[:] = gravity + kp * (wound - data.qpos[motor]) - kd * data.qvel[motor]
        mujoco.mj_step(model, data, spec.substeps)
    link = data.qpos[motor] + data.qpos[spring]
    return float(np.abs(link - posture).max()), float(np.abs(data.qvel).max())


def test_too_few_substeps_for_the_springs_are_refused_in_one_clear_line():
    stiff = PlantSpec(inertials="cad", stiffness=STIFFNESS_PRESETS["stiff"], substeps=1)
    with pytest.raises(ValueError, match=r"^substeps=1 is too few .*A7.* needs substeps >= 7$"):
        compile_model(stiff)
    # What the guard prevents: the same plant, compiled around it, diverges at once.
    error, _ = _hold(stiff, np.array(READY_POSTURE), seconds=0.2)
    assert not np.isfinite(error)
    # Undamped springs need a short step: ω·dt ≤ 1 for the CAD wrist's 446 Hz.
    undamped = PlantSpec(inertials="cad", spring_damping=(0.0,) * 7)
    with pytest.raises(ValueError, match=r"needs substeps >= 6$"):
        compile_model(undamped)
    assert step_ratios(undamped.model_copy(update={"substeps": 6})).max() <= 0.25
    # Rigid joints have no springs to integrate: any step will do.
    compile_model(PlantSpec(joints="rigid", substeps=1))
    compile_model(PlantSpec())  # the default plant


def test_an_unstable_simulation_leaves_no_log_file_and_prints_nothing(tmp_path):
    # MuJoCo's default for its warnings: a line on stdout and MUJOCO_LOG.TXT in the cwd.
    script = (
        "import mujoco\n"
        "from gainfarm.models import compile_model\n"
        "from gainfarm.schemas.robot import PlantSpec\n"
        "model = compile_model(PlantSpec())\n"
        "data = mujoco.MjData(model)\n"
        "data.qpos[:] = 1e20\n"
        "mujoco.mj_step(model, data)\n"
        "print(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout == "1\n"  # the warning happened, and nothing but the script printed
    assert list(tmp_path.iterdir()) == []
