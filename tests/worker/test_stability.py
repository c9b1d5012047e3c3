"""The damping margin (worker.stability): the linearised tick loop predicts the simulator's ticks,
and its least damping ratio tells a controller that settles from one that chatters, on real
MuJoCo episodes."""

import mujoco
import numpy as np
import pytest

from gainfarm.models.urdf import description
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.mcap_episode import decode_episode, episode_bytes
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import IDEAL_PLANT, ModelSpec, Sensors
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.wire import WireScores
from gainfarm.worker.control import PDController
from gainfarm.worker.episode import _setup, compensation, run_episode
from gainfarm.worker.plant import Plant
from gainfarm.worker.reference import reference_for
from gainfarm.worker.stability import ClosedLoop, damping_ratios, least_damping
from gainfarm.worker.stepping import Stepped, step_all

PATH = TrajectorySpec(kind="fourier", duration=2.0)


def scaled(kp: float, kd: float) -> PDGains:
    return PDGains(
        kp=tuple(kp * gain for gain in DEFAULT_GAINS.kp),
        kd=tuple(kd * gain for gain in DEFAULT_GAINS.kd),
    )


def test_damping_ratios_of_known_eigenvalues() -> None:
    dt = 0.002
    s = -0.3 * 50 + 1j * 50 * np.sqrt(1 - 0.3**2)  # ζ = 0.3 at 50 rad/s
    z = np.array([0.0, 0.5, np.exp(s * dt), np.exp(1j * 0.4), 1.01 * np.exp(1j * 0.4), -1.0])
    ratios = damping_ratios(z)
    assert ratios[0] == 1.0 and ratios[1] == pytest.approx(1.0)  # deadbeat, real decay
    assert ratios[2] == pytest.approx(0.3)
    assert ratios[3] == pytest.approx(0.0, abs=1e-12)  # on the unit circle: undamped
    assert ratios[4] < 0  # outside it: growing
    assert ratios[5] == pytest.approx(0.0, abs=1e-12)  # a sign flip every tick, undamped


def _run(spec: EpisodeSpec, offset: np.ndarray | None = None) -> Stepped:
    """The real tick loop on `spec`, its plant's state at tick 0 moved by `offset`."""
    reference = reference_for(spec.trajectory)
    episode = _setup(spec, reference, compensation(spec, reference))
    if offset is not None:
        model, data = episode.plant.model, episode.plant.data
        data.qpos[:] += offset[: model.nq]
        data.qvel[:] += offset[model.nq :]
        mujoco.mj_forward(model, data)
    step_all([episode])
    return episode


EXACT_COUNTS = Sensors(resolution=0, noise=0)  # no quantisation: the loop is smooth


@pytest.mark.parametrize(
    "model",
    [
        ModelSpec(sensors=EXACT_COUNTS),  # FRI, elastic, window 3, delay 1, friction
        ModelSpec(sensors=EXACT_COUNTS, interface="torque"),
        ModelSpec(
            joints="rigid", delay=2, sensors=Sensors(resolution=0, noise=0, velocity_window=2)
        ),
        IDEAL_PLANT,  # the exact loop: no window, no delay
    ],
    ids=["realistic", "plain", "rigid-delay-2", "ideal"],
)
def test_the_linear_model_predicts_the_tick_loop(model: ModelSpec) -> None:
    """A small perturbation of the state at tick 0, carried through ten ticks of the linearised
    loop (each tick's matrix at the unperturbed episode's state), lands where the simulator's
    own tick loop takes it: every register (window, delay) and term (FRI gravity, friction)
    of the linear model is the loop's."""
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH.model_copy(update={"duration": 0.5}))
    spec = spec.model_copy(update={"model": model})
    nominal = _run(spec)
    plant = nominal.plant
    nx = plant.model.nq + plant.model.nv
    offset = np.random.default_rng(1).standard_normal(nx) * 1e-6
    perturbed = _run(spec, offset)
    loop = ClosedLoop(Plant(model), PDController.from_gains(spec.gains, plant.torque_limits))
    z = np.zeros(loop.size)
    z[:nx] = offset
    if loop.delay:  # the robot holds the first command until the delay has passed
        delayed = slice(nx + 7 * loop.window, loop.size)
        first = loop.at(
            nominal.state[0][: nx // 2], nominal.state[0][nx // 2 :], _motor(nominal, 0)
        )
        z[delayed] = np.tile(first[delayed][:7] @ z, loop.delay)
    for tick in range(10):
        state = nominal.state[tick]
        z = loop.at(state[: nx // 2], state[nx // 2 :], _motor(nominal, tick)) @ z
        moved = perturbed.state[tick + 1] - nominal.state[tick + 1]
        assert np.linalg.norm(z[:nx] - moved) <= 2e-3 * np.linalg.norm(moved), tick


def _motor(episode: Stepped, tick: int) -> np.ndarray:
    """The motors' torque at `tick` of a run: the command acting then (and the robot's gravity
    model's), and the motors' friction."""
    plant, spec = episode.plant, episode.plant.spec
    limits = plant.torque_limits
    torque = np.clip(episode.command[max(tick - spec.delay, 0)], -limits, limits)
    if episode.fri:
        torque = torque + episode.compensation[tick]
    if spec.friction is not None:
        velocity = plant.motor_map @ episode.state[tick][plant.model.nq :]
        torque = torque - np.asarray(spec.friction.coulomb) * np.tanh(
            velocity / spec.friction.smoothing
        )
    return torque


def test_the_default_gains_keep_a_positive_margin_and_settle() -> None:
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH)
    margin = least_damping(spec)
    assert 0 < margin < 0.2  # the arm's elastic mode of A2 at some 58 Hz is the least damped
    scores = score(run_episode(spec))
    assert not scores.diverged and scores.chatter < Limits().chatter


def test_a_destabilising_gain_set_has_a_negative_margin_and_chatters() -> None:
    """Five times the default damping, read through a differenced velocity one tick late: the
    elastic mode grows, and on the real plant the command chatters between its torque limits."""
    spec = EpisodeSpec(gains=scaled(1, 5), trajectory=PATH)
    assert least_damping(spec) < 0
    scores = score(run_episode(spec))
    assert scores.chatter > 10 * Limits().chatter
    assert scores.torque_step > 10 * Limits().torque_step


def test_the_log_and_its_scores_carry_the_margin() -> None:
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH.model_copy(update={"duration": 0.5}))
    log = run_episode(spec)
    assert log.metadata.damping == least_damping(spec)
    decoded = decode_episode(episode_bytes(log, description()), "test")
    assert decoded.metadata.damping == log.metadata.damping
    scores = score(decoded)
    assert scores.damping == log.metadata.damping
    assert WireScores(**scores.model_dump()).damping == scores.damping
