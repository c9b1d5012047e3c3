"""The generic builder (models/mjcf_arm.py) on a vendored arm: what it does to any MJCF."""

import dataclasses

import mujoco
import numpy as np
import pytest

from gainfarm.models import PlantError, ur5e
from gainfarm.models.mjcf_arm import PAYLOAD_RADIUS
from gainfarm.schemas.robot import Friction, LoadData, PlantSpec

ARM = ur5e.ROBOT
HOME = np.asarray(ARM.workspace.home)


def plant(**changes: object) -> PlantSpec:
    return PlantSpec(robot=ARM.name, **changes)  # type: ignore[arg-type]


def test_the_file_s_position_servos_become_plain_torque_motors() -> None:
    # Menagerie's default actuator class is a position servo (force = kp (ctrl - q)): the motors
    # must not inherit its bias, or every command is off by the joint's angle.
    model = ARM.build(plant(joints="rigid"))
    data = mujoco.MjData(model)
    data.qpos[:] = HOME
    data.ctrl[:] = [10.0, -5.0, 3.0, 1.0, -1.0, 0.5]
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.qfrc_actuator, data.ctrl, atol=1e-12)
    np.testing.assert_allclose(model.actuator_ctrlrange[:, 1], ARM.limits.torque)


def test_rotor_friction_and_limits_replace_the_file_s_joint_numbers() -> None:
    rotor = (0.2, 0.3, 0.4, 0.05, 0.06, 0.07)
    viscous = (1.0, 2.0, 3.0, 0.1, 0.2, 0.3)
    friction = Friction(viscous=viscous, coulomb=(0.0,) * 6)
    model = ARM.build(plant(joints="rigid", rotor_inertia=rotor, friction=friction))
    np.testing.assert_allclose(model.dof_armature, rotor)
    np.testing.assert_allclose(model.dof_damping, viscous)  # Menagerie's 200 and 15 are gone
    np.testing.assert_allclose(model.jnt_range[:, 1], ARM.limits.position)
    assert model.dof_frictionloss.max() == 0.0 and model.jnt_stiffness.max() == 0.0
    assert ARM.build(plant(joints="rigid", friction=None)).dof_damping.max() == 0.0


def test_each_spring_turns_about_its_motor_s_axis_with_the_spec_s_numbers() -> None:
    stiffness = (1000.0, 1100.0, 1200.0, 300.0, 310.0, 320.0)
    spec = plant(stiffness=stiffness, spring_damping=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0))
    model = ARM.build(spec)
    for i, name in enumerate(ARM.joint_names):
        motor, spring = model.joint(f"{name}_motor"), model.joint(f"{name}_spring")
        assert motor.bodyid == spring.bodyid
        np.testing.assert_allclose(model.jnt_axis[spring.id], model.jnt_axis[motor.id])
        assert model.jnt_stiffness[spring.id] == stiffness[i]
        assert model.dof_damping[model.jnt_dofadr[spring.id]] == spec.spring_damping[i]
        assert not model.jnt_limited[spring.id] and model.jnt_limited[motor.id]


def test_mass_scale_weighs_the_body_each_joint_turns() -> None:
    base = ARM.build(plant(joints="rigid"))
    scale = (1.0, 2.0, 1.0, 1.0, 1.0, 0.5)
    heavier = ARM.build(plant(joints="rigid", mass_scale=scale))
    for name, factor in zip(ARM.joint_names, scale, strict=True):
        body = base.joint(name).bodyid[0]
        assert heavier.body_mass[body] == pytest.approx(factor * base.body_mass[body])
        np.testing.assert_allclose(heavier.body_inertia[body], factor * base.body_inertia[body])


def test_payload_and_told_load_hang_at_the_flange() -> None:
    model = ARM.build(plant(joints="rigid", payload=2.0))
    payload = model.body("payload")
    data = mujoco.MjData(model)
    data.qpos[:] = HOME
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.xipos[payload.id], data.site(ARM.flange).xpos, atol=1e-9)
    assert model.body_mass[payload.id] == 2.0
    assert model.body_inertia[payload.id][0] == pytest.approx(0.4 * 2.0 * PAYLOAD_RADIUS**2)
    # A load 5 cm out along the flange's axis, heavier than told by half: below the flange
    # (the axis points down at home), of its true mass; the robot's own model knows the told.
    load = LoadData(mass=1.0, com=(0.0, 0.0, 0.05), mass_scale=1.5)
    model = ARM.build(plant(joints="rigid", load=load))
    data = mujoco.MjData(model)
    data.qpos[:] = HOME
    mujoco.mj_kinematics(model, data)
    below = data.site(ARM.flange).xpos - np.array([0.0, 0.0, 0.05])
    np.testing.assert_allclose(data.xipos[model.body("load").id], below, atol=1e-9)
    assert model.body_mass[model.body("load").id] == 1.5
    told = ARM.build(ARM.gravity_spec(plant(load=load)))
    assert told.body_mass[told.body("load").id] == 1.0


def test_the_build_is_cached_per_plant_and_its_step_is_the_tick_over_substeps() -> None:
    spec = plant(substeps=4)
    assert ARM.build(spec) is ARM.build(spec.model_copy())
    assert ARM.build(spec).opt.timestep == pytest.approx(0.002 / 4)
    assert ARM.build(spec).opt.disableflags & mujoco.mjtDisableBit.mjDSBL_AUTORESET


def test_an_inertial_set_the_arm_lacks_is_refused_naming_the_field() -> None:
    with pytest.raises(
        PlantError, match=r"^inertials: ur5e has no set 'cad' \(it has menagerie\)$"
    ):
        ARM.build(plant(inertials="cad"))


def test_a_file_whose_joints_differ_is_refused_naming_them() -> None:
    other = dataclasses.replace(ARM, name="other", file_joints=("a", "b", "c", "d", "e", "f"))
    with pytest.raises(ValueError, match=r"ur5e.xml: joints .*, expected \['a'"):
        other.describe(plant())
