"""The load the robot is told (KUKA's load data): the plant holds it and the robot's own gravity
model (FRI) carries it, so a told load is compensated and an untold one sags the arm."""

import mujoco
import numpy as np

from gainfarm.models import compile_model
from gainfarm.schemas import EpisodeSpec, PlantSpec, TrajectorySpec
from gainfarm.schemas.robot import JOINT_NAMES, LoadData
from gainfarm.worker.episode import run_episode
from gainfarm.worker.plant import ArmsGravity, RobotGravity, gravity_spec
from tests.helpers import SOFT_GAINS

TOLD = LoadData(mass=5.0, com=(0.03, -0.02, 0.08))
ANGLES = np.random.default_rng(7).uniform(-1.5, 1.5, (20, 7))


def plant_gravity(spec: PlantSpec, angles: np.ndarray) -> np.ndarray:
    """(n, 7) N·m gravity puts on the links of `spec`'s simulated plant at link angles `angles`
    (the springs' side of elastic joints: the torque the robot must hold)."""
    model = compile_model(spec)
    data = mujoco.MjData(model)
    links = [model.joint(f"{name}_spring").dofadr[0] for name in JOINT_NAMES]
    motors = [model.joint(f"{name}_motor").qposadr[0] for name in JOINT_NAMES]
    torques = np.empty_like(angles)
    for row, torque in zip(angles, torques, strict=True):
        data.qpos[:] = 0.0
        data.qpos[motors] = row  # springs undeflected: the link angle is the motor's
        mujoco.mj_forward(model, data)
        torque[:] = data.qfrc_bias[links]  # zero velocity: gravity alone
    return torques


def test_a_told_load_is_what_the_robots_gravity_model_holds_up() -> None:
    told = PlantSpec(load=TOLD)
    np.testing.assert_allclose(
        RobotGravity(told).at(ANGLES), plant_gravity(told, ANGLES), atol=1e-9
    )
    # The same load untold (an undeclared payload, the sphere at the flange's centre), or told
    # but heavier than told: the robot's model holds up the bare arm, or the told mass, only.
    load_torque = plant_gravity(told, ANGLES) - plant_gravity(PlantSpec(), ANGLES)
    assert np.abs(load_torque).max() > 20  # 5 kg on a long arm: tens of N·m at A2
    untold = PlantSpec(payload=5.0)
    np.testing.assert_array_equal(
        RobotGravity(untold).at(ANGLES), RobotGravity(PlantSpec()).at(ANGLES)
    )
    heavier = PlantSpec(load=TOLD.model_copy(update={"mass_scale": 1.2}))
    assert gravity_spec(heavier) == gravity_spec(told)
    missing = plant_gravity(heavier, ANGLES) - RobotGravity(heavier).at(ANGLES)
    np.testing.assert_allclose(missing, 0.2 * load_torque, atol=1e-6)


def test_many_arms_gravity_gives_a_loaded_arm_the_bits_its_own_model_gives() -> None:
    specs = [
        PlantSpec(load=TOLD),
        PlantSpec(),
        PlantSpec(inertials="cad", load=LoadData(mass=2.0)),
        PlantSpec(load=TOLD.model_copy(update={"mass_scale": 0.9})),  # told alike: the same
    ]
    arms = ArmsGravity(specs)
    for tick in np.random.default_rng(3).uniform(-2.0, 2.0, (30, len(specs), 7)):
        arms.angles[:] = tick
        arms.compute()
        alone = [RobotGravity(spec).at(row[None])[0] for spec, row in zip(specs, tick, strict=True)]
        assert np.array_equal(arms.torque, np.stack(alone))
    arms.angles[:] = ANGLES[0]
    arms.compute()
    assert not np.array_equal(arms.torque[0], arms.torque[1])  # the load counts
    assert np.array_equal(arms.torque[0], arms.torque[3])


def test_a_told_load_tracks_far_better_than_the_same_load_untold() -> None:
    # Soft gains, so that the robot's gravity model, not the PD's stiffness, holds the load.
    path = TrajectorySpec(kind="fourier", duration=2.0)
    plants = {
        "told": PlantSpec(load=LoadData(mass=5.0)),
        "untold": PlantSpec(payload=5.0),  # the same sphere at the flange's centre
        "bare": PlantSpec(),
    }
    error = {}
    for name, plant in plants.items():
        log = run_episode(EpisodeSpec(gains=SOFT_GAINS, trajectory=path, plant=plant))
        assert not log.metadata.diverged
        error[name] = np.sqrt(np.mean(np.sum((log.ee - log.ee_des) ** 2, axis=1)))  # RMS, m
    assert error["told"] < 0.5 * error["untold"], error
    # What the load adds to the bare arm's error: its inertia, told or not, but not its weight.
    assert error["told"] - error["bare"] < 0.25 * (error["untold"] - error["bare"]), error


def test_the_load_is_centred_where_the_robot_was_told_in_the_flange_frame() -> None:
    model = compile_model(PlantSpec(load=TOLD))
    data = mujoco.MjData(model)
    for row in ANGLES[:5]:
        data.qpos[[model.joint(f"{name}_motor").qposadr[0] for name in JOINT_NAMES]] = row
        mujoco.mj_forward(model, data)
        flange = model.site("flange").id
        told = data.site_xpos[flange] + data.site_xmat[flange].reshape(3, 3) @ TOLD.com
        np.testing.assert_allclose(data.xipos[model.body("load").id], told, atol=1e-12)
    assert model.body_mass[model.body("load").id] == TOLD.mass


def test_an_untold_payload_is_centred_on_the_flange_as_documented() -> None:
    # models/README.md: a sphere centred on the flange, where the told load's default centre is
    # and where a calibration fits a payload (it sat 4.5 cm further out before).
    model = compile_model(PlantSpec(payload=2.0))
    data = mujoco.MjData(model)
    data.qpos[[model.joint(f"{name}_motor").qposadr[0] for name in JOINT_NAMES]] = ANGLES[0]
    mujoco.mj_forward(model, data)
    flange = data.site_xpos[model.site("flange").id]
    np.testing.assert_allclose(data.xipos[model.body("payload").id], flange, atol=1e-12)
    told = compile_model(PlantSpec(load=LoadData(mass=2.0)))
    assert np.array_equal(told.body("load").pos, model.body("payload").pos)
    assert np.array_equal(told.body("load").ipos, model.body("payload").ipos)
