"""What a real joint has, simulated: friction, actuation delay, encoders, torque sensors; and the
ideal plant, which must stay the first wave's episode exactly."""

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from gainfarm.models import compile_model, resolve
from gainfarm.schemas import EpisodeSpec, PDGains, TrajectorySpec
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import IDEAL_PLANT, REALISTIC_PLANT, Friction, PlantSpec, Sensors
from gainfarm.schemas.trajectory import CONTROL_PERIOD
from gainfarm.worker.episode import gravity_torques, run_episode, simulate
from gainfarm.worker.reference import Reference
from gainfarm.worker.sensors import Encoders
from tests.helpers import TRACKING_GAINS

DATA = Path(__file__).parent / "data"
SHORT = TrajectorySpec(kind="fourier", duration=1.0)
EXACT_RIGID = IDEAL_PLANT.model_copy(update={"joints": "rigid"})


def _joint_space_reference(q: np.ndarray, ee: np.ndarray | None = None) -> Reference:
    """A reference given directly in joint space (flange positions only matter if given)."""
    qd = np.gradient(q, CONTROL_PERIOD, axis=0)
    return Reference(
        t=np.arange(len(q)) * CONTROL_PERIOD,
        ee=np.zeros((len(q), 3)) if ee is None else ee,
        q=q,
        qd=qd,
        qdd=np.gradient(qd, CONTROL_PERIOD, axis=0),
    )


def test_the_ideal_plant_reproduces_the_first_waves_episodes_exactly():
    # References and scores recorded with the code of 7cdc091, before the plant had friction,
    # delay, sensors or inertial sets: the ideal plant must give the very same numbers.
    arrays = np.load(DATA / "ideal_episodes.npz")
    records = json.loads((DATA / "ideal_episodes.json").read_text())
    for i, record in enumerate(records):
        old = record["spec"]
        model = IDEAL_PLANT.model_copy(
            update={"joints": old["model"]["joints"], "substeps": old["model"]["substeps"]}
        )
        spec = EpisodeSpec(
            gains=PDGains(**old["gains"]),
            plant=model,
            gravity_compensation=old["gravity_compensation"],
        )
        q = arrays[f"q{i}"]
        reference = _joint_space_reference(q, arrays[f"ee{i}"])
        gravity = gravity_torques(q, "open") if spec.gravity_compensation else None
        log = simulate(spec, reference, gravity)
        scores = score(log).model_dump(mode="json")  # and the safety measures, recorded since
        assert {name: scores[name] for name in record["scores"]} == record["scores"], i


def test_coulomb_friction_adds_its_level_to_the_torque_that_moves_a_joint_steadily():
    # A1 (vertical axis: no gravity torque) turning at a steady 0.3 rad/s under a stiff PD.
    q = np.tile([0.0, 0.5, 0.0, -1.6, 0.0, 1.0, 0.0], (751, 1))
    q[:, 0] = 0.3 * np.arange(751) * CONTROL_PERIOD
    reference = _joint_space_reference(q)
    stiff = PDGains(kp=(3000,) * 7, kd=(300, 300, 100, 100, 20, 10, 5))
    coulomb = (6.0, 0, 0, 0, 0, 0, 0)
    torques = {}
    for name, friction in (
        ("without", Friction(viscous=(0.0,) * 7, coulomb=(0.0,) * 7)),
        ("with", Friction(viscous=(0.0,) * 7, coulomb=coulomb)),
    ):
        model = EXACT_RIGID.model_copy(update={"friction": friction})
        log = simulate(EpisodeSpec(gains=stiff, plant=model), reference, None)
        torques[name] = log.u[500:, 0].mean()  # after the start-up transient
    assert torques["with"] - torques["without"] == pytest.approx(6.0, rel=0.02)


def test_viscous_friction_lands_on_the_motor_hinge():
    model = compile_model(PlantSpec(friction=Friction(viscous=(0.7,) * 7)))
    motors = [model.joint(f"A{i}_motor").id for i in range(1, 8)]
    np.testing.assert_allclose(model.dof_damping[model.jnt_dofadr[motors]], 0.7)


@pytest.mark.parametrize("delay", [1, 3])
def test_a_delayed_command_shifts_the_response_by_the_delay(delay):
    # Open loop (feed-forward only): the arm rests until the first command acts, then moves as
    # it would without delay, `delay` ticks later.
    q = np.tile([0.0, 0.5, 0.0, -1.6, 0.0, 1.0, 0.0], (300, 1))
    reference = _joint_space_reference(q)
    gravity = gravity_torques(q, "open")
    gravity[150:] *= 1.05  # a step in the feed-forward half way
    runs = {}
    for d in (0, delay):
        model = EXACT_RIGID.model_copy(update={"delay": d})
        spec = EpisodeSpec(gains=PDGains(kp=(0,) * 7, kd=(0,) * 7), plant=model)
        runs[d] = simulate(
            spec.model_copy(update={"gravity_compensation": True}), reference, gravity
        )
    np.testing.assert_allclose(runs[delay].u[delay:], runs[0].u[:-delay], atol=1e-12)
    np.testing.assert_allclose(runs[delay].q[delay:], runs[0].q[:-delay], atol=1e-9)
    assert np.abs(runs[0].q[-1] - runs[0].q[0]).max() > 1e-4  # it did move


def test_sensor_noise_is_reproducible_from_the_seed_and_differs_between_seeds():
    def run(seed: int):
        model = REALISTIC_PLANT.model_copy(update={"sensors": Sensors(seed=seed)})
        return run_episode(EpisodeSpec(gains=TRACKING_GAINS, trajectory=SHORT, plant=model))

    first, again, other = run(0), run(0), run(1)
    for name in ("q", "qd", "tau", "u", "theta", "theta_d"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name), name)
    assert not np.array_equal(first.q, other.q)
    assert not np.array_equal(first.tau, other.tau)


def test_encoders_report_whole_counts_and_velocity_from_their_differences(tracking_log):
    sensors = tracking_log.metadata.spec.plant.sensors
    encoders = Encoders(sensors, tracking_log.q.shape[1])
    for angles, velocities in (
        (tracking_log.q, tracking_log.qd),
        (tracking_log.theta, tracking_log.theta_d),
    ):
        counts = angles / sensors.resolution
        np.testing.assert_allclose(counts, np.rint(counts), atol=1e-6)
        w = encoders.window
        differenced = (angles[w:] - angles[:-w]) / (w * CONTROL_PERIOD)
        np.testing.assert_allclose(velocities[w:], differenced, atol=1e-9)


def test_the_torque_sensors_read_the_spring_torque_with_their_noise(tracking_log):
    spec = tracking_log.metadata.spec
    clean = run_episode(
        spec.model_copy(
            update={"plant": spec.plant.model_copy(update={"sensors": Sensors(torque_noise=0.0)})}
        )
    )
    noise = tracking_log.tau - clean.tau
    assert noise.std() == pytest.approx(spec.plant.sensors.torque_noise, rel=0.05)
    # Holding the arm up, A2's spring carries tens of N·m; the command differs from it
    assert np.abs(clean.tau[:, 1]).mean() > 20
    assert np.abs(tracking_log.u - tracking_log.tau).max() > 1.0


def test_on_the_ideal_elastic_plant_the_log_explains_its_own_torque_command():
    # u = ID(q, q̇, q̈) + B θ̈: rigid inverse dynamics of the logged link state (without the
    # rotor inertia) plus the rotor inertia times the logged motor acceleration.
    spec = EpisodeSpec(
        gains=TRACKING_GAINS, trajectory=TrajectorySpec(duration=3.0), plant=IDEAL_PLANT
    )
    log = run_episode(spec)
    links = compile_model(
        PlantSpec(joints="rigid", inertials="open", friction=None, rotor_inertia=(0.0,) * 7)
    )
    data = mujoco.MjData(links)
    qdd = np.diff(log.qd, axis=0) / CONTROL_PERIOD
    thetadd = np.diff(log.theta_d, axis=0) / CONTROL_PERIOD
    explained = np.empty_like(qdd)
    for k in range(len(qdd)):
        data.qpos[:], data.qvel[:], data.qacc[:] = log.q[k], log.qd[k], qdd[k]
        mujoco.mj_inverse(links, data)
        explained[k] = data.qfrc_inverse + np.array(resolve(spec.plant).rotor_inertia) * thetadd[k]
    u = log.u[:-1]
    nmse = ((explained - u) ** 2).mean(axis=0) / u.var(axis=0)
    assert nmse.max() < 1e-5, nmse
