import mujoco
import numpy as np
import pytest

from gainfarm.models import compile_model, resolve
from gainfarm.models.urdf import description
from gainfarm.schemas import EpisodeSpec, PDGains, PlantSpec, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.mcap_episode import decode_episode, episode_bytes
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import IDEAL_PLANT, PLAIN_PLANT, REALISTIC_PLANT
from gainfarm.worker.control import PDController
from gainfarm.worker.episode import (
    _log,
    _setup,
    gravity_for,
    gravity_torques,
    motor_torque,
    run_episode,
)
from gainfarm.worker.plant import Plant, RobotGravity
from gainfarm.worker.reference import reference_for
from gainfarm.worker.stepping import step_all
from tests.helpers import SOFT_GAINS, TRACKING_GAINS

SHORT = TrajectorySpec(duration=3.0)
IDEAL_RIGID = IDEAL_PLANT.model_copy(update={"joints": "rigid"})


LIMP = PDGains(kp=(0,) * 7, kd=(0,) * 7)


def test_without_torque_the_arm_falls_under_gravity():
    log = run_episode(EpisodeSpec(gains=LIMP, trajectory=SHORT, plant=PLAIN_PLANT))
    assert np.all(log.u == 0)
    assert log.ee[min(100, log.ticks - 1), 2] < log.ee[0, 2] - 0.05  # dropped 5 cm in 0.2 s
    assert log.metadata.diverged  # and it keeps falling until it leaves the joint range


def test_behind_fri_the_robots_own_gravity_model_holds_the_arm_up():
    # No gains at all: the robot's gravity compensation alone keeps the arm where it started
    # (the reference moves on without it: the error grows, but nothing falls).
    still = TrajectorySpec(kind="fourier", duration=1.0)
    log = run_episode(EpisodeSpec(gains=LIMP, trajectory=still))
    assert log.metadata.spec.plant.interface == "fri" and not log.metadata.diverged
    assert np.all(log.u == 0)
    assert np.abs(log.ee - log.ee[0]).max() < 1e-3  # not a millimetre of sag in 1 s
    assert np.abs(log.ee_des - log.ee_des[0]).max() > 0.01  # while the reference moved
    # A payload the robot's model does not know: the arm sags under it, as a real one would.
    loaded = run_episode(EpisodeSpec(gains=LIMP, trajectory=still, plant=PlantSpec(payload=2.0)))
    assert loaded.ee[-1, 2] < log.ee[-1, 2] - 0.05


def test_the_robot_adds_its_own_models_gravity_not_the_plants():
    # No gains: a rigid arm's joint torque sensors read what the motors exert, the robot's
    # gravity model at the measured angles, which holds the arm whose masses it knows.
    still = TrajectorySpec(kind="fourier", duration=0.5)
    rigid = PlantSpec(joints="rigid", substeps=1, delay=0, friction=None)
    log = run_episode(EpisodeSpec(gains=LIMP, trajectory=still, plant=rigid))
    np.testing.assert_allclose(log.tau[-1], gravity_torques(log.q[-1:], "menagerie")[0], atol=0.5)
    assert abs(log.tau[-1, 1]) > 30  # A2 holds tens of N·m
    assert np.abs(log.ee - log.ee[0]).max() < 1e-6  # and holds it: rigid, no delay, exact


@pytest.mark.parametrize(
    "plant",
    [
        REALISTIC_PLANT,  # noisy counts of the motor side, fed back
        REALISTIC_PLANT.model_copy(update={"feedback": "link", "payload": 5.0}),
        IDEAL_PLANT.model_copy(update={"interface": "fri"}),  # exact sensors, link side
        PLAIN_PLANT,
    ],
    ids=["realistic", "link side, payload", "ideal behind FRI", "plain torque"],
)
def test_the_log_gives_the_torque_the_motors_exerted_bit_for_bit(plant: PlantSpec, tmp_path):
    # What a dataset's u_motor is made of: the logged command and the logged fed-back angles
    # through the robot's gravity model give the loop's own compensation, number for number,
    # alone and in a stack, after the MCAP round trip.
    spec = EpisodeSpec(
        gains=TRACKING_GAINS, trajectory=TrajectorySpec(kind="fourier", duration=0.6), plant=plant
    )
    reference = reference_for(spec.trajectory)
    alone, *stack = (_setup(spec, reference, None) for _ in range(3))
    step_all([alone])
    step_all(stack)
    limits = Plant(plant).torque_limits
    for run in (alone, stack[1]):
        log = decode_episode(episode_bytes(_log(spec, run), description()))
        assert log.ticks == run.ticks_run == reference.t.size
        if plant.interface == "torque":
            np.testing.assert_array_equal(motor_torque(log), log.u)
            continue
        loops = run.compensation[: run.ticks_run]
        measured = log.theta if plant.feedback == "motor" else log.q
        np.testing.assert_array_equal(RobotGravity(plant).at(measured), loops)
        exerted = np.clip(log.u + loops, -limits, limits)  # as MuJoCo clamps the loop's ctrl
        np.testing.assert_array_equal(motor_torque(log), exerted)
        assert np.abs(exerted - log.u)[:, 1].min() > 10  # A2's gravity: not the command alone


def test_high_gains_track_far_better_than_low_gains():
    soft = score(run_episode(EpisodeSpec(gains=SOFT_GAINS, trajectory=SHORT)))
    stiff = score(run_episode(EpisodeSpec(gains=DEFAULT_GAINS, trajectory=SHORT)))
    assert not soft.diverged and not stiff.diverged
    assert stiff.f_acc < 0.5 * soft.f_acc


def test_applied_torques_obey_the_pd_law_and_never_exceed_the_limits():
    aggressive = PDGains(kp=(8000,) * 7, kd=(50, 50, 50, 50, 10, 5, 2))
    log = run_episode(EpisodeSpec(gains=aggressive, trajectory=SHORT, plant=IDEAL_PLANT))
    limits = np.array(log.metadata.torque_limits)
    assert np.all(np.abs(log.u) <= limits)
    assert np.any(np.abs(log.u) == limits)  # these gains do saturate
    law = PDController.from_gains(aggressive, limits)
    np.testing.assert_allclose(
        log.u, law.torque(log.q, log.qd, log.q_des, log.qd_des), rtol=1e-9, atol=1e-9
    )


def test_the_realistic_pd_acts_on_measured_motor_angles_one_tick_late(tracking_log):
    # The default plant: the PD sees the motor encoders' angles and their differenced velocity,
    # and its command acts one tick later (the first command holds until then).
    spec = tracking_log.metadata.spec
    assert spec.plant.feedback == "motor" and spec.plant.delay == 1
    law = PDController.from_gains(spec.gains, np.array(tracking_log.metadata.torque_limits))
    computed = law.torque(
        tracking_log.theta, tracking_log.theta_d, tracking_log.q_des, tracking_log.qd_des
    )
    np.testing.assert_allclose(tracking_log.u[1:], computed[:-1], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(tracking_log.u[0], computed[0], rtol=1e-9, atol=1e-9)


def test_episode_starts_at_rest_on_the_reference(tracking_log):
    # to within the encoders' noise and counts
    np.testing.assert_allclose(tracking_log.q[0], tracking_log.q_des[0], atol=5e-5)
    np.testing.assert_allclose(tracking_log.theta[0], tracking_log.q_des[0], atol=5e-5)
    np.testing.assert_allclose(tracking_log.qd[0], 0.0, atol=0.05)
    np.testing.assert_allclose(tracking_log.ee[0], tracking_log.ee_des[0], atol=1e-3)
    assert tracking_log.ticks == SHORT.ticks


def test_gravity_compensation_improves_tracking():
    # On a plain torque interface, as a feed-forward; behind FRI, as the robot does it.
    plain = score(
        run_episode(EpisodeSpec(gains=TRACKING_GAINS, trajectory=SHORT, plant=PLAIN_PLANT))
    )
    compensated = score(
        run_episode(
            EpisodeSpec(
                gains=TRACKING_GAINS,
                trajectory=SHORT,
                plant=PLAIN_PLANT,
                gravity_compensation=True,
            )
        )
    )
    fri = score(run_episode(EpisodeSpec(gains=TRACKING_GAINS, trajectory=SHORT)))
    assert compensated.f_acc < 0.5 * plain.f_acc and fri.f_acc < 0.5 * plain.f_acc


def test_gravity_compensation_twice_is_refused():
    with pytest.raises(ValueError, match="interface fri: the robot already adds"):
        EpisodeSpec(gains=TRACKING_GAINS, gravity_compensation=True)


def test_flexible_joints_deflect_under_load_and_rigid_ones_cannot():
    spec = IDEAL_PLANT
    plant = Plant(spec)
    reference = reference_for(SHORT)
    plant.reset(reference.q[0])
    gravity = gravity_torques(reference.q[:1], spec.inertials)[0]
    plant.data.ctrl[:] = gravity
    mujoco.mj_step(plant.model, plant.data, 500)  # settle, holding gravity with the motors
    deflection = plant.data.qpos[1::2]  # the spring hinges: link angle minus motor angle
    expected = -gravity / np.array(resolve(spec).stiffness)
    np.testing.assert_allclose(deflection[1], expected[1], rtol=0.1)
    assert abs(deflection[1]) > 1e-3
    assert Plant(PlantSpec(joints="rigid")).model.nq == 7


def test_flexible_and_rigid_robots_behave_differently_under_the_same_gains():
    rigid = run_episode(
        EpisodeSpec(gains=TRACKING_GAINS, trajectory=SHORT, plant=PlantSpec(joints="rigid"))
    )
    flexible = run_episode(EpisodeSpec(gains=TRACKING_GAINS, trajectory=SHORT))
    assert np.abs(rigid.q - flexible.q).max() > 1e-4


def test_divergence_ends_the_episode_early_with_a_valid_flagged_log(diverged_log):
    meta = diverged_log.metadata
    assert meta.diverged and "at t =" in meta.divergence
    assert 0 < meta.ticks_run < meta.ticks_planned == SHORT.ticks
    assert diverged_log.ticks == meta.ticks_run
    for column in (diverged_log.q, diverged_log.tau, diverged_log.u, diverged_log.theta):
        assert np.isfinite(column).all()


def test_same_spec_gives_the_same_episode(tracking_log):
    again = run_episode(tracking_log.metadata.spec)
    np.testing.assert_array_equal(again.q, tracking_log.q)
    for name in ("q", "qd", "tau", "u", "theta", "theta_d", "ee"):
        np.testing.assert_array_equal(getattr(again, name), getattr(tracking_log, name), name)


def test_logged_flange_positions_are_the_kinematics_of_the_logged_joint_angles():
    # The flange is logged mid-tick (after the first physics step); it must still be this tick's.
    log = run_episode(EpisodeSpec(gains=TRACKING_GAINS, trajectory=SHORT, plant=IDEAL_PLANT))
    model = compile_model(PlantSpec(joints="rigid"))
    data = mujoco.MjData(model)
    for k in (0, 1, 500, log.ticks - 1):
        data.qpos[:] = log.q[k]
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(data.site("flange").xpos, log.ee[k], atol=1e-9)


def test_gravity_feedforward_holds_the_reference_posture():
    spec = TrajectorySpec(duration=3.0)
    reference = reference_for(spec)
    gravity = gravity_for(spec, "cad")
    # A2 carries most of the arm: tens of N·m, as at the home posture.
    assert 20 < abs(gravity[0, 1]) < 80
    model = compile_model(PlantSpec(joints="rigid", inertials="cad"))
    data = mujoco.MjData(model)
    data.qpos[:] = reference.q[1000]
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(gravity[1000], data.qfrc_bias)
    with pytest.raises(ValueError):  # cached and shared, so read-only
        gravity[0] = 1.0
