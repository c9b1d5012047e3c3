"""One episode: the system, control and sensor/actuator layers stepping together at 500 Hz.

Here an episode is set up (its plant at rest, its controller as matrices, its noise and
feed-forward drawn into per-tick rows) and its log made from what the tick loop recorded (the
torques clamped, the sensors' readings the controller did not use, in bulk); the tick loop
itself, for one episode or many stepped together, is worker.stepping. There are two: the first
wave's lean loop for exact sensors without delay or friction (the ideal plant, kept bit for
bit), and the realistic one, with encoders, a delay and motor friction.
"""

import platform
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache, lru_cache
from importlib.metadata import version
from typing import Any

import mujoco
import numpy as np

from gainfarm.models import resolve, written_out
from gainfarm.models.dynamics import DynamicsModel, friction_torque, plant_spec, true_model
from gainfarm.schemas.episode import EpisodeMetadata, EpisodeSpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.robot import DEFAULT_ROBOT, LoadData, PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD, TrajectorySpec
from gainfarm.worker.control import PDController
from gainfarm.worker.plant import Plant, RobotGravity
from gainfarm.worker.reference import Reference, reference_for
from gainfarm.worker.sensors import LINK, MOTOR, TORQUE, Encoders, noise
from gainfarm.worker.stability import least_damping
from gainfarm.worker.stepping import Stepped, step_all


class MissingModel(ValueError):
    """The spec names a feed-forward model the caller did not give."""


def run_episode(spec: EpisodeSpec, model: DynamicsModel | None = None) -> EpisodeLog:
    """Simulate `spec` and return its log. A diverging episode is stopped early and flagged.
    `model` is the inverse-dynamics model the spec's `feedforward` names, if it names one."""
    reference = reference_for(spec.trajectory, spec.plant.robot)
    return simulate(spec, reference, compensation(spec, reference, model))


def compensation(
    spec: EpisodeSpec, reference: Reference, model: DynamicsModel | None = None
) -> np.ndarray | None:
    """The torque the controller adds to its PD law, per tick: the gravity feed-forward, or a
    learned model's inverse dynamics of the whole reference, computed in bulk once per episode
    so that the tick stays as lean as without; None if the spec asks for neither. `reference`
    is the spec trajectory's (reference_for).

    A model predicts the whole motor torque, gravity included (`motor_torque`); behind FRI the
    robot adds its own gravity model at the measured angles, so the controller adds the model's
    torque less that gravity model's at the reference, or gravity would be counted twice."""
    if spec.feedforward is not None:
        if model is None:
            raise MissingModel(f"feed-forward model {spec.feedforward[:12]} was not given")
        torque = model.inverse(reference.q, reference.qd, reference.qdd)
        if spec.plant.interface == "fri":  # g_robot(q_des), computed once per trajectory
            torque = torque - gravity_for(
                spec.trajectory, spec.plant.inertials, spec.plant.load, spec.plant.robot
            )
        return torque
    if spec.gravity_compensation:
        return gravity_for(spec.trajectory, spec.plant.inertials, spec.plant.load, spec.plant.robot)
    return None


def true_compensation(
    spec: EpisodeSpec, reference: Reference, delay: bool = False, deflection: bool = False
) -> np.ndarray:
    """`compensation` with the plant's own model (models.dynamics.true_model) of the spec's
    plant, and optionally what that model cannot say, for `simulate`:

    - `delay`: the torque the reference needs `spec.plant.delay` ticks ahead, when the command
      acts (the last tick's held at the end);
    - `deflection`: on elastic joints fed back from the motor side, the PD steers the motor
      angle θ, and the link lags it by the spring's deflection τ_link / K (τ_link the torque the
      spring carries: the true arm's without its rotors and friction, which act before it). The
      motor's reference becomes q_des + τ_link / K, which the linear PD law takes as the added
      torque Kp·δ + Kd·δ̇; behind FRI the robot's gravity model then sees θ ≈ q_des + δ.

    Neither is a model file's to say (they need the gains, the tick and the springs), so the
    farm's jobs run the plain true model; bench/true_feedforward.py measures both."""
    model, plant = true_model(spec.plant), resolve(spec.plant)
    torque = model.inverse(reference.q, reference.qd, reference.qdd)
    motor_angles = reference.q
    if deflection and plant.joints == "flexible" and plant.feedback == "motor":
        links = plant_spec(plant).model_copy(
            update={"rotor_inertia": (0.0,) * reference.q.shape[1], "friction": None}
        )
        carried = true_model(links).inverse(reference.q, reference.qd, reference.qdd)
        bend = carried / np.asarray(plant.stiffness)
        rate = np.gradient(bend, CONTROL_PERIOD, axis=0)
        torque += np.asarray(spec.gains.kp) * bend + np.asarray(spec.gains.kd) * rate
        motor_angles = reference.q + bend
    if plant.interface == "fri":
        torque -= gravity_torques(motor_angles, plant.inertials, plant.load, plant.robot)
    ahead = plant.delay if delay else 0
    return np.vstack([torque[ahead:], np.repeat(torque[-1:], ahead, axis=0)])


def simulate(spec: EpisodeSpec, reference: Reference, added: np.ndarray | None) -> EpisodeLog:
    """Track `reference` with the spec's controller on its plant, `added` (see `compensation`)
    added to the PD law's torque."""
    return simulate_all([(spec, reference, added)])[0]


Prepared = tuple[EpisodeSpec, Reference, np.ndarray | None]  # what `simulate` takes


def simulate_all(
    episodes: Sequence[Prepared],
    threads: int = 1,
    then: Callable[[EpisodeLog], Any] | None = None,
) -> list:
    """`simulate` each of `episodes`, all stepped together on `threads` threads (see
    worker.stepping); each log is the same, byte for byte, as if its episode ran alone. With
    `then`, each log's `then(log)` instead, computed on the thread that stepped it. A plant's
    numbers left to its robot are written out (models.resolve): the log says what ran."""
    episodes = [(written_out(spec), *rest) for spec, *rest in episodes]
    stepped = [_setup(*episode) for episode in episodes]
    index = {id(run): position for position, run in enumerate(stepped)}
    done: list = [None] * len(stepped)

    def finish(run: Stepped) -> None:
        position = index[id(run)]
        log = _log(episodes[position][0], run)
        done[position] = log if then is None else then(log)

    step_all(stepped, threads, finish)
    return done


def _setup(spec: EpisodeSpec, reference: Reference, added: np.ndarray | None) -> Stepped:
    """The episode's plant at rest where the reference starts, its controller as matrices."""
    plant = Plant(spec.plant)
    controller = PDController.from_gains(spec.gains, plant.torque_limits)
    feedforward = controller.reference_term(
        reference.q, reference.qd, 0.0 if added is None else added
    )
    plant.reset(reference.q[0])
    if _exact(spec.plant):
        kp_state, kd_state = controller.state_gains(plant.feedback_map)
        gains = np.hstack([kp_state, kd_state])  # Kp q + Kd q̇ = gains @ (qpos, qvel)
        return Stepped(plant, reference, gains, feedforward)
    sensing = _Sensing.of(plant, controller)
    friction = plant.spec.friction  # the resolved plant's: the robot's own unless the spec says
    fri = spec.plant.interface == "fri"
    return Stepped(
        plant,
        reference,
        sensing.pd_law,
        sensing.rows(plant, feedforward),
        measure=sensing.measure,
        rest=sensing.at_rest(plant),
        window=sensing.window,
        quantised=sensing.quantised,
        slip=sensing.slip,
        opposing=None if friction is None else -np.asarray(friction.coulomb),
        fri=fri,
        unit=1.0 if spec.plant.sensors.exact else sensing.encoders.count,
    )


def _log(spec: EpisodeSpec, run: Stepped) -> EpisodeLog:
    """The episode's log from what its loop recorded."""
    plant, reference, ticks_run = run.plant, run.reference, run.ticks_run
    state = run.state[:ticks_run]
    if run.exact:
        # MuJoCo clamped each command to the motor's ctrlrange (the torque limit) when applying
        # it; clamping is exact, so doing the same here in bulk logs exactly the torques applied.
        applied = np.clip(run.command[:ticks_run], -plant.torque_limits, plant.torque_limits)
        readings = _exact_readings(plant, state, applied, applied)
    else:
        delay = np.maximum(np.arange(ticks_run) - spec.plant.delay, 0)
        applied = np.clip(run.command[delay], -plant.torque_limits, plant.torque_limits)
        motor = applied  # what the motors exert: the command, and the robot's gravity model's
        if run.fri:
            motor = np.clip(
                applied + run.compensation[:ticks_run], -plant.torque_limits, plant.torque_limits
            )
        if spec.plant.sensors.exact:
            readings = _exact_readings(plant, state, applied, motor)
        else:
            counts = run.measured[: run.window + ticks_run, : plant.joints]
            encoders = Encoders(spec.plant.sensors, plant.joints)
            readings = _sensed_readings(plant, encoders, state, counts, applied, motor)
    metadata = EpisodeMetadata(
        spec=spec,
        ticks_planned=run.ticks,
        ticks_run=ticks_run,
        torque_limits=tuple(plant.torque_limits.tolist()),
        # What the log's readers need of its robot and cannot look up (the contract knows no
        # robot): its joints' names and speed limits (an iiwa 14's leave them out: as before).
        joint_names=plant.robot.joint_names,
        speed_limits=plant.robot.limits.speed,
        diverged=bool(run.divergence),
        divergence=run.divergence,
        versions=software_versions(),
        damping=least_damping(spec, reference),
    )
    return EpisodeLog(
        t=reference.t[:ticks_run].copy(),
        **readings,
        q_des=reference.q[:ticks_run].copy(),
        qd_des=reference.qd[:ticks_run].copy(),
        ee=run.flange[:ticks_run].copy(),
        ee_des=reference.ee[:ticks_run].copy(),
        metadata=metadata,
    )


def _exact(plant: PlantSpec) -> bool:
    """Whether the first wave's lean loop runs the episode: exact sensors, no delay, no friction,
    the command the motor torque (the ideal plant, whichever side it feeds back from)."""
    return (
        plant.sensors.exact
        and plant.delay == 0
        and plant.friction is None
        and plant.interface == "torque"
    )


def motor_torque(log: EpisodeLog) -> np.ndarray:
    """(ticks, joints) N·m the motors exerted, from the log alone: behind FRI, its command `u` plus
    the robot's gravity model at the angles the robot measured (the fed-back side's, as logged:
    the loop's very numbers), clamped to the torque limits as the robot does; on a plain torque
    interface, `u` itself. What a model of the arm's dynamics predicts."""
    model = log.metadata.spec.plant
    if model.interface != "fri":
        return log.u
    measured = log.theta if model.feedback == "motor" else log.q
    limits = np.asarray(log.metadata.torque_limits)
    return np.clip(log.u + RobotGravity(model).at(measured), -limits, limits)


@lru_cache(maxsize=64)
def gravity_for(
    trajectory: TrajectorySpec,
    inertials: str,
    load: LoadData | None = None,
    robot: str = DEFAULT_ROBOT,
) -> np.ndarray:
    """The gravity feed-forward of `trajectory`'s reference on `robot`, computed once per
    worker: the robot's own gravity model (`RobotGravity`) at the reference's angles."""
    torques = gravity_torques(reference_for(trajectory, robot).q, inertials, load, robot)
    torques.flags.writeable = False
    return torques


def gravity_torques(
    q: np.ndarray, inertials: str, load: LoadData | None = None, robot: str = DEFAULT_ROBOT
) -> np.ndarray:
    """(n, joints) N·m holding link angles `q` against gravity. The controller's gravity model is
    the robot's own (`RobotGravity`: for the iiwa 14, the plant's own inertial set, as KUKA's
    controller knows its robot, and the load it is told)."""
    return RobotGravity(PlantSpec(robot=robot, inertials=inertials, load=load)).at(q)


@dataclass(frozen=True)
class _Sensing:
    """How the loop turns a row (qpos, qvel, noise, feed-forward) into its command.

    A measurement is (fed-back angles [and their velocities, if exact], θ̇ / smoothing,
    feed-forward); with encoders the angles are noisy counts and the velocity the mean of their
    differences over `window` ticks, folded into `pd_law`.
    """

    encoders: Encoders
    measure: np.ndarray  # (width, nx + 2·joints): a tick's measurement = measure @ row
    pd_law: np.ndarray  # (joints, width · (window + 1)): command = pd_law @ recent measurements
    window: int  # rows of past measurements the PD law reads besides the current one
    quantised: bool
    slip: slice  # where θ̇ / smoothing sits in a measurement

    @property
    def width(self) -> int:
        return len(self.measure)

    @classmethod
    def of(cls, plant: Plant, controller: PDController) -> "_Sensing":
        n, nq, nx = plant.joints, plant.model.nq, plant.model.nq + plant.model.nv
        spec = plant.spec
        encoders = Encoders(spec.sensors, n)
        exact = spec.sensors.exact
        sensed = 2 * n if exact else n  # angles and velocities, or counts of angles
        measure = np.zeros((sensed + 2 * n, nx + 2 * n))
        if exact:
            measure[:n, :nq] = plant.feedback_map
            measure[n:sensed, nq:nx] = plant.feedback_map
            gains = np.hstack([np.diag(controller.kp), np.diag(controller.kd)])
            window, quantised = 0, False
        else:
            measure[:n, :nq] = plant.feedback_map / encoders.count
            measure[:n, nx : nx + n] = np.eye(n)
            gains = encoders.pd_gains(controller.kp, controller.kd)
            window, quantised = encoders.window, encoders.quantised
        slip = slice(sensed, sensed + n)
        if spec.friction is not None:
            measure[slip, nq:nx] = plant.motor_map / spec.friction.smoothing
        measure[sensed + n :, nx + n :] = np.eye(n)  # the feed-forward passes through
        # command = feed-forward − (Kp·angle + Kd·velocity), over the window of measurements
        width = len(measure)
        pd_law = np.zeros((n, width * (window + 1)))
        for age in range(window + 1):  # oldest first, as the window lies in memory
            pd_law[:, width * age : width * age + sensed] = -gains[
                :, sensed * age : sensed * (age + 1)
            ]
        pd_law[:, width * window + sensed + n :] = np.eye(n)
        return cls(encoders, measure, pd_law, window, quantised, slip)

    def rows(self, plant: Plant, feedforward: np.ndarray) -> np.ndarray:
        """(ticks, nx + 2·joints) rows with the noise and feed-forward filled in, the state to
        come."""
        n, nx = plant.joints, plant.model.nq + plant.model.nv
        rows = np.zeros((len(feedforward), nx + 2 * n))
        if not plant.spec.sensors.exact:
            side = LINK if plant.spec.feedback == "link" else MOTOR
            rows[:, nx : nx + n] = self.encoders.noise(side, len(feedforward))
        rows[:, nx + n :] = feedforward
        return rows

    def at_rest(self, plant: Plant) -> np.ndarray:
        """What the sensors read before the episode, the arm resting where it starts (only the
        angles matter: the PD law reads nothing else from past measurements)."""
        rest = np.zeros(self.width)
        if not plant.spec.sensors.exact:
            rest[: plant.joints] = self.encoders.counts(plant.feedback_map @ plant.data.qpos)
        return rest


def _exact_readings(
    plant: Plant, state: np.ndarray, applied: np.ndarray, motor: np.ndarray
) -> dict[str, np.ndarray]:
    """The log's sensor columns when the sensors are exact: the simulator's state as is.
    `applied` is the command as the robot took it, `motor` the torque its motors exerted."""
    qpos, qvel = np.split(state, [plant.model.nq], axis=1)
    return {
        "q": qpos @ plant.link_map.T,
        "qd": qvel @ plant.link_map.T,
        "tau": _joint_torque(plant, qpos, qvel, motor),
        "u": applied,
        "theta": qpos @ plant.motor_map.T,
        "theta_d": qvel @ plant.motor_map.T,
    }


def _sensed_readings(
    plant: Plant,
    encoders: Encoders,
    state: np.ndarray,
    counts: np.ndarray,
    applied: np.ndarray,
    motor: np.ndarray,
) -> dict[str, np.ndarray]:
    """The log's sensor columns as the robot's sensors report them.

    The fed-back side's counts are the ones the controller saw; the other side is measured now,
    in bulk, with its own noise stream (the same as measuring it in the loop: nothing in the
    loop depends on it).
    """
    spec = plant.spec
    ticks = len(state)
    nq, nx = plant.model.nq, plant.model.nq + plant.model.nv
    qpos, qvel = state[:, :nq], state[:, nq:nx]
    readings = {}
    for side, angle_map, stream in (
        ("link", plant.link_map, LINK),
        ("motor", plant.motor_map, MOTOR),
    ):
        if side == spec.feedback:
            side_counts = counts
        else:
            angles = qpos @ angle_map.T
            measured = encoders.counts(angles, encoders.noise(stream, ticks))
            side_counts = encoders.padded(measured, encoders.counts(angles[0]))
        readings[side] = encoders.read(side_counts)
    torque = _joint_torque(plant, qpos, qvel, motor)
    torque_noise = noise(spec.sensors, TORQUE, ticks, spec.sensors.torque_noise, plant.joints)
    return {
        "q": readings["link"][0],
        "qd": readings["link"][1],
        "tau": torque + torque_noise,
        "u": applied,
        "theta": readings["motor"][0],
        "theta_d": readings["motor"][1],
    }


def _joint_torque(
    plant: Plant, qpos: np.ndarray, qvel: np.ndarray, motor: np.ndarray
) -> np.ndarray:
    """What the joint torque sensors measure: the spring torque of an elastic joint; for a rigid
    one, the motor's torque less its friction."""
    if plant.elastic:
        return plant.joint_torque(qpos, qvel)
    return motor - friction_torque(plant.spec.friction, qvel @ plant.motor_map.T)


@cache
def software_versions() -> dict[str, str]:
    return {
        "gainfarm": version("gainfarm"),
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }
