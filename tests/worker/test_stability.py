"""The damping margin (worker.stability): the linearised tick loop predicts the simulator's ticks,
and its least damping ratio tells a controller that settles from one that chatters, on real
MuJoCo episodes; `margins` splits the tracking modes from the elastic ones and finds how much
command delay the tracking modes take."""

import mujoco
import numpy as np
import pytest

from gainfarm.models import resolve
from gainfarm.models.urdf import description
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.mcap_episode import decode_episode, episode_bytes
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import IDEAL_PLANT, PlantSpec, Sensors
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.wire import WireScores
from gainfarm.worker.control import PDController
from gainfarm.worker.episode import _setup, compensation, run_episode
from gainfarm.worker.plant import Plant
from gainfarm.worker.reference import reference_for
from gainfarm.worker.stability import (
    MAX_EXTRA_DELAY,
    ClosedLoop,
    Margins,
    damping_ratios,
    least_damping,
    margins,
)
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
    "plant_spec",
    [
        PlantSpec(sensors=EXACT_COUNTS),  # FRI, elastic, window 3, delay 1, friction
        PlantSpec(sensors=EXACT_COUNTS, interface="torque"),
        PlantSpec(
            joints="rigid", delay=2, sensors=Sensors(resolution=0, noise=0, velocity_window=2)
        ),
        IDEAL_PLANT,  # the exact loop: no window, no delay
    ],
    ids=["realistic", "plain", "rigid-delay-2", "ideal"],
)
def test_the_linear_model_predicts_the_tick_loop(plant_spec: PlantSpec) -> None:
    """A small perturbation of the state at tick 0, carried through ten ticks of the linearised
    loop (each tick's matrix at the unperturbed episode's state), lands where the simulator's
    own tick loop takes it: every register (window, delay) and term (FRI gravity, friction)
    of the linear model is the loop's."""
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH.model_copy(update={"duration": 0.5}))
    spec = spec.model_copy(update={"plant": plant_spec})
    nominal = _run(spec)
    plant = nominal.plant
    nx = plant.model.nq + plant.model.nv
    offset = np.random.default_rng(1).standard_normal(nx) * 1e-6
    perturbed = _run(spec, offset)
    loop = ClosedLoop(Plant(plant_spec), PDController.from_gains(spec.gains, plant.torque_limits))
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


# --- margins: the tracking modes' own damping, the delay margin --------------------------------

# The default gains but a tenth of their Kd on A1 and A2: the big joints' tracking modes barely
# damped, which least_damping (its least mode an elastic one) does not see.
UNDER_DAMPED = PDGains(
    kp=DEFAULT_GAINS.kp,
    kd=tuple(k * f for k, f in zip(DEFAULT_GAINS.kd, (0.1, 0.1, 1, 1, 1, 1, 1), strict=True)),
)
TOP_DELAY = 2  # ticks: the top of models/uncertainty.toml's `delay` range (the nominal is 1)
ROTOR_10X = PlantSpec(rotor_inertia=tuple(10 * r for r in resolve(PlantSpec()).rotor_inertia))


def test_the_default_gains_track_with_damping_to_spare_two_ticks_late() -> None:
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH)
    found = margins(spec, delay=TOP_DELAY)
    assert found.least == least_damping(spec)
    assert found.elastic is not None and found.elastic_hz is not None
    # The two classes are every mode: the least of them is least_damping's (to its rounding).
    assert min(found.tracking, found.elastic) == pytest.approx(found.least, abs=2e-6)
    assert found.tracking > 0 and found.tracking_at > 0
    assert found.tracking_at < found.tracking  # a tick more delay takes some damping
    assert found.delay == TOP_DELAY and found.delay_margin >= TOP_DELAY - spec.plant.delay
    # The least damped mode is a spring's, fast; the controller's own are slower and better damped.
    assert found.elastic < found.tracking and found.tracking_hz < found.elastic_hz


def test_an_under_damped_controller_loses_its_tracking_modes_two_ticks_late() -> None:
    """least_damping passes it (its least mode is a spring's, as the default gains'); its
    tracking modes go unstable with one tick more delay, where the defaults' keep theirs."""
    default = margins(EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH), delay=TOP_DELAY)
    weak = margins(EpisodeSpec(gains=UNDER_DAMPED, trajectory=PATH), delay=TOP_DELAY)
    assert weak.least > 0 and weak.tracking > 0  # stable at its own delay
    assert weak.tracking < default.tracking
    assert weak.tracking_at <= 0 < default.tracking_at
    assert weak.delay_margin < default.delay_margin


def _late(spec: EpisodeSpec, extra: int) -> float:
    """The tracking damping of `spec`'s loop `extra` ticks later than its plant's delay."""
    return margins(spec, delay=spec.plant.delay + extra).tracking_at


@pytest.mark.parametrize(
    "gains",
    [DEFAULT_GAINS, UNDER_DAMPED, scaled(3, 1), scaled(1, 0.1)],
    ids=["default", "under-damped", "stiff", "kd-0.1x"],
)
def test_the_delay_margin_is_the_last_delay_the_tracking_modes_take(gains: PDGains) -> None:
    spec = EpisodeSpec(gains=gains, trajectory=PATH)
    found = margins(spec)
    assert -1 <= found.delay_margin < MAX_EXTRA_DELAY and not found.capped
    assert found.tracking_at == found.tracking  # no delay asked: the plant's own
    for extra in range(found.delay_margin + 1):
        assert _late(spec, extra) > 0, extra
    assert _late(spec, found.delay_margin + 1) <= 0


def test_a_delay_margin_past_the_search_reads_as_its_cap() -> None:
    """Heavy rotors (ten times the nominal inertia) and three times the default Kd: the slow
    tracking modes shrug off delay, stable still at the search's last tick."""
    spec = EpisodeSpec(gains=scaled(1, 3), trajectory=PATH, plant=ROTOR_10X)
    found = margins(spec)
    assert found.delay_margin == MAX_EXTRA_DELAY and found.capped
    assert _late(spec, MAX_EXTRA_DELAY) > 0


def test_a_delay_asked_of_margins_is_the_plant_with_that_delay() -> None:
    """The delay lives in the loop's delay line alone: the plant linearised with its own
    delay of 2 ticks gives the same loop as the nominal plant's linearisation 2 ticks late."""
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH)
    late = spec.model_copy(update={"plant": spec.plant.model_copy(update={"delay": TOP_DELAY})})
    asked, own = margins(spec, delay=TOP_DELAY), margins(late)
    assert (asked.tracking_at, asked.tracking_at_hz) == (own.tracking, own.tracking_hz)
    assert own.least == least_damping(late)
    with pytest.raises(ValueError, match="delay -1"):
        margins(spec, delay=-1)


def test_the_split_follows_the_plant_not_a_frequency() -> None:
    """On the realistic, ideal and ten-times-rotor plants the default gains' least damped
    tracking mode is slower than their least damped elastic one; on rigid joints every mode
    tracks. The heavy rotors' elastic modes are slower than the search space's top gains'
    tracking mode on the realistic plant two ticks late: no one frequency splits the two kinds
    on every plant."""
    found: dict[str, Margins] = {}
    for name, model in {"realistic": PlantSpec(), "ideal": IDEAL_PLANT, "rotor": ROTOR_10X}.items():
        found[name] = margins(EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH, plant=model))
        assert found[name].elastic_hz is not None, name
        assert found[name].tracking_hz < found[name].elastic_hz, name
    rigid = margins(
        EpisodeSpec(gains=DEFAULT_GAINS, trajectory=PATH, plant=PlantSpec(joints="rigid"))
    )
    assert rigid.elastic is None and rigid.elastic_hz is None
    assert rigid.tracking == pytest.approx(rigid.least, abs=2e-6)
    top = margins(EpisodeSpec(gains=scaled(3, 5), trajectory=PATH), delay=TOP_DELAY)
    assert found["rotor"].elastic_hz < top.tracking_at_hz
    assert found["rotor"].elastic_hz < 0.5 * found["realistic"].elastic_hz
