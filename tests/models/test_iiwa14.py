import subprocess
import sys

import mujoco
import numpy as np
import pytest

from models import build_spec, compile_model
from schemas import TORQUE_LIMITS, ModelSpec

HOME = np.array([0.0, 0.785398, 0.0, -1.5708, 0.0, 0.0, 0.0])


def test_rigid_model_matches_the_published_numbers():
    model = compile_model(ModelSpec(joints="rigid"))
    data = mujoco.MjData(model)
    assert (model.nq, model.nu) == (7, 7)
    # Total mass of the seven links and the base, from the data sheet's table.
    assert model.body_mass.sum() == pytest.approx(30.61, abs=0.01)
    np.testing.assert_allclose(model.actuator_ctrlrange[:, 1], TORQUE_LIMITS)
    data.qpos[:] = HOME
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.site("flange").xpos, [0.669, 0.0, 0.285], atol=1e-3)
    # Gravity torques at home: the reference quotes about 57 N·m on A2 and 17 N·m on A4.
    assert abs(data.qfrc_bias[1]) == pytest.approx(57, abs=1)
    assert abs(data.qfrc_bias[3]) == pytest.approx(17, abs=1)


def test_flexible_variant_is_generated_from_the_same_chain():
    spec = ModelSpec(stiffness=(1234.0,) * 7)
    rigid = compile_model(ModelSpec(joints="rigid"))
    flexible = compile_model(spec)
    assert flexible.nq == 14
    names = [flexible.joint(j).name for j in range(flexible.njnt)]
    assert names[:4] == ["A1_motor", "A1_spring", "A2_motor", "A2_spring"]
    np.testing.assert_allclose(flexible.body_mass, rigid.body_mass)
    np.testing.assert_allclose(flexible.body_pos, rigid.body_pos)
    np.testing.assert_allclose(flexible.jnt_stiffness[1::2], 1234.0)
    np.testing.assert_allclose(flexible.dof_armature[0::2], spec.rotor_inertia)
    # The motors drive the motor-side hinges.
    assert [flexible.joint(j).name for j in flexible.actuator_trnid[:, 0]] == [
        f"A{i}_motor" for i in range(1, 8)
    ]


def test_control_period_is_split_into_the_requested_substeps():
    assert compile_model(ModelSpec(substeps=4)).opt.timestep == pytest.approx(0.0005)


def test_exported_mjcf_compiles_to_the_same_model():
    xml = build_spec(ModelSpec()).to_xml()
    reloaded = mujoco.MjModel.from_xml_string(xml)
    assert reloaded.nq == 14
    np.testing.assert_allclose(reloaded.jnt_stiffness, compile_model(ModelSpec()).jnt_stiffness)


def test_an_unstable_simulation_leaves_no_log_file_and_prints_nothing(tmp_path):
    # MuJoCo's default for its warnings: a line on stdout and MUJOCO_LOG.TXT in the cwd.
    script = (
        "import mujoco\n"
        "from models import compile_model\n"
        "from schemas.robot import ModelSpec\n"
        "model = compile_model(ModelSpec())\n"
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
