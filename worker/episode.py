"""One episode: the system, control and sensor/actuator layers stepping together at 500 Hz.

The tick loop is the hot path (thousands of episodes, thousands of ticks each). There are two:
the first wave's lean loop for exact sensors without delay or friction (the ideal plant, kept
bit for bit), and the realistic one, with encoders, a delay and motor friction. Each only senses,
does a few small matrix-vector products and steps the physics; everything else (reference,
feed-forward, noise, torque clamping in the log, the sensors' readings that the controller does
not use, divergence checks) is done in bulk, once per episode or once per block of ticks.
"""

import platform
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache, lru_cache
from importlib.metadata import version

import mujoco
import numpy as np

from gainfarm.models import compile_model
from gainfarm.models.dynamics import DynamicsModel
from gainfarm.schemas.episode import EpisodeMetadata, EpisodeSpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.robot import JOINT_NAMES, ModelSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD, TrajectorySpec
from gainfarm.worker.control import PDController
from gainfarm.worker.plant import Plant
from gainfarm.worker.reference import Reference, reference_for
from gainfarm.worker.sensors import LINK, MOTOR, TORQUE, Encoders, friction_torque, noise

CHECK_EVERY = 250  # ticks between divergence checks (0.5 s): cheap, and early enough
MAX_JOINT_ERROR = 1.0  # rad: a tracking error this large is a lost arm, not a tuning trade-off
_STATE = mujoco.mjtState.mjSTATE_QPOS | mujoco.mjtState.mjSTATE_QVEL  # what a tick senses


class MissingModel(ValueError):
    """The spec names a feed-forward model the caller did not give."""


def run_episode(spec: EpisodeSpec, model: DynamicsModel | None = None) -> EpisodeLog:
    """Simulate `spec` and return its log. A diverging episode is stopped early and flagged.
    `model` is the inverse-dynamics model the spec's `feedforward` names, if it names one."""
    reference = reference_for(spec.trajectory)
    return simulate(spec, reference, compensation(spec, reference, model))


def compensation(
    spec: EpisodeSpec, reference: Reference, model: DynamicsModel | None = None
) -> np.ndarray | None:
    """The torque the controller adds to its PD law, per tick: the gravity feed-forward, or a
    learned model's inverse dynamics of the whole reference, computed in bulk once per episode
    so that the tick stays as lean as without; None if the spec asks for neither."""
    if spec.feedforward is not None:
        if model is None:
            raise MissingModel(f"feed-forward model {spec.feedforward[:12]} was not given")
        return model.inverse(reference.q, reference.qd, reference.qdd)
    if spec.gravity_compensation:
        return gravity_for(spec.trajectory, spec.model.inertials)
    return None


def simulate(spec: EpisodeSpec, reference: Reference, added: np.ndarray | None) -> EpisodeLog:
    """Track `reference` with the spec's controller on its plant, `added` (see `compensation`)
    added to the PD law's torque."""
    plant = Plant(spec.model)
    controller = PDController.from_gains(spec.gains, plant.torque_limits)
    feedforward = controller.reference_term(
        reference.q, reference.qd, 0.0 if added is None else added
    )
    plant.reset(reference.q[0])

    ticks = len(reference.t)
    flange = np.empty((ticks, 3))
    command = np.empty((ticks, len(JOINT_NAMES)))
    if _exact(spec.model):
        state = np.empty((ticks, plant.model.nq + plant.model.nv))
        ticks_run, divergence = _simulate_exact(
            plant, controller, feedforward, reference, state, command, flange
        )
        # MuJoCo clamped each command to the motor's ctrlrange (the torque limit) when applying
        # it; clamping is exact, so doing the same here in bulk logs exactly the torques applied.
        applied = np.clip(command[:ticks_run], -plant.torque_limits, plant.torque_limits)
        readings = _exact_readings(plant, state[:ticks_run], applied)
    else:
        sensing = _Sensing.of(plant, controller)
        rows = sensing.rows(plant, feedforward)
        measured = np.empty((sensing.window + ticks, sensing.width))
        measured[: sensing.window] = sensing.at_rest(plant)  # no rows if the sensors are exact
        ticks_run, divergence = _simulate(
            plant, sensing, reference, rows, measured, command, flange
        )
        delay = np.maximum(np.arange(ticks_run) - spec.model.delay, 0)
        applied = np.clip(command[delay], -plant.torque_limits, plant.torque_limits)
        state = rows[:ticks_run, : plant.model.nq + plant.model.nv]
        if spec.model.sensors.exact:
            readings = _exact_readings(plant, state, applied)
        else:
            counts = measured[: sensing.window + ticks_run, : len(JOINT_NAMES)]
            readings = _sensed_readings(plant, sensing.encoders, state, counts, applied)

    metadata = EpisodeMetadata(
        spec=spec,
        ticks_planned=ticks,
        ticks_run=ticks_run,
        torque_limits=tuple(plant.torque_limits.tolist()),
        diverged=bool(divergence),
        divergence=divergence,
        versions=software_versions(),
    )
    return EpisodeLog(
        t=reference.t[:ticks_run].copy(),
        **readings,
        q_des=reference.q[:ticks_run].copy(),
        qd_des=reference.qd[:ticks_run].copy(),
        ee=flange[:ticks_run],
        ee_des=reference.ee[:ticks_run].copy(),
        metadata=metadata,
    )


def _exact(model: ModelSpec) -> bool:
    """Whether the first wave's lean loop runs the episode: exact sensors, no delay, no friction
    (the ideal plant, whichever side it feeds back from)."""
    return model.sensors.exact and model.delay == 0 and model.friction is None


@lru_cache(maxsize=64)
def gravity_for(trajectory: TrajectorySpec, inertials: str) -> np.ndarray:
    """The gravity feed-forward of `trajectory`'s reference, computed once per worker."""
    torques = gravity_torques(reference_for(trajectory).q, inertials)
    torques.flags.writeable = False
    return torques


def gravity_torques(q: np.ndarray, inertials: str) -> np.ndarray:
    """(n, 7) N·m holding link angles `q` against gravity. The controller's gravity model is the
    plant's own inertial set (as KUKA's controller knows its robot)."""
    model = compile_model(ModelSpec(joints="rigid", inertials=inertials, friction=None, substeps=1))
    data = mujoco.MjData(model)
    torques = np.empty_like(q)
    for k, qk in enumerate(q):
        data.qpos[:] = qk
        mujoco.mj_forward(model, data)  # qvel = 0, so the bias force is gravity alone
        torques[k] = data.qfrc_bias
    return torques


def _simulate_exact(
    plant: Plant,
    controller: PDController,
    feedforward: np.ndarray,
    reference: Reference,
    state_log: np.ndarray,
    torque_log: np.ndarray,
    flange_log: np.ndarray,
) -> tuple[int, str]:
    """The tick loop with exact sensors and no delay; return (ticks kept, divergence or "").

    Each tick: sense the state, set the PD command, take the first physics step, then log the
    flange position (mj_step computes kinematics before it integrates, so site_xpos is still this
    tick's), then take the remaining substeps. The command is logged unclamped; MuJoCo clamps it
    to the motor's ctrlrange when applying it, and the log does the same in bulk.
    """
    model, data = plant.model, plant.data
    ctrl, flange = data.ctrl, data.site_xpos[plant.flange]
    kp_state, kd_state = controller.state_gains(plant.feedback_map)
    state_gain = np.hstack([kp_state, kd_state])  # Kp q + Kd q̇ = state_gain @ (qpos, qvel)
    feedback = np.empty(len(controller.kp))
    sense, signature = mujoco.mj_getState, _STATE
    step = mujoco.mj_step
    remaining_substeps = plant.substeps - 1
    dot, subtract, copy = np.dot, np.subtract, np.copyto
    ticks = len(feedforward)
    for start, stop in _blocks(ticks):
        block = zip(
            state_log[start:stop],
            torque_log[start:stop],
            flange_log[start:stop],
            feedforward[start:stop],
            strict=True,
        )
        for state, torque, flange_position, reference_term in block:
            sense(model, data, state, signature)
            dot(state_gain, state, out=feedback)
            subtract(reference_term, feedback, out=ctrl)
            copy(torque, ctrl)
            step(model, data)
            copy(flange_position, flange)
            if remaining_substeps:
                step(model, data, remaining_substeps)
        if stopped := _stopped(plant, state_log, reference, start, stop):
            return stopped
    return ticks, ""


def _simulate(
    plant: Plant,
    sensing: "_Sensing",
    reference: Reference,
    row_log: np.ndarray,
    measured_log: np.ndarray,
    command_log: np.ndarray,
    flange_log: np.ndarray,
) -> tuple[int, str]:
    """The tick loop with sensors, delay and friction; return (ticks kept, divergence or "").

    Each row of `row_log` is (qpos, qvel, encoder noise, feed-forward): all but the state were
    known before the episode, so one matrix-vector product turns a sensed row into a measurement
    (what the PD sees, the motors' friction argument θ̇ / smoothing, the feed-forward). Rows of
    `measured_log` follow `window` rows measured at rest, so the last window + 1 of them are one
    contiguous vector and the PD command is one more product. Each tick: sense, measure, compute
    the command; apply the command computed `delay` ticks ago (the first one until then: the
    robot was already holding it); set the motors' Coulomb friction for this tick from their
    velocities; step as in `_simulate_exact`.
    """
    model, data = plant.model, plant.data
    n, nx, window = len(JOINT_NAMES), plant.model.nq + plant.model.nv, sensing.window
    ctrl, flange = data.ctrl, data.site_xpos[plant.flange]
    measure, pd_law = sensing.measure, sensing.pd_law
    flat = measured_log.reshape(-1)
    windows = np.lib.stride_tricks.as_strided(
        flat,
        shape=(len(command_log), sensing.width * (window + 1)),
        strides=(sensing.width * flat.itemsize, flat.itemsize),
    )
    delayed = [command_log[max(k - plant.spec.delay, 0)] for k in range(len(command_log))]
    friction = plant.spec.friction
    motor_force = data.qfrc_applied[plant.motor_dof_slice]  # a view: writes land in MuJoCo
    opposing = -np.asarray(friction.coulomb) if friction is not None else None
    sense, signature = mujoco.mj_getState, _STATE
    step = mujoco.mj_step
    remaining_substeps = plant.substeps - 1
    quantised = sensing.quantised
    dot, multiply, copy, rint, tanh = np.dot, np.multiply, np.copyto, np.rint, np.tanh
    states = row_log[:, :nx]
    measurements = measured_log[window:]
    angles = measurements[:, :n]  # counts of the fed-back angles (or the angles, if exact)
    slips = measurements[:, sensing.slip]
    ticks = len(command_log)
    for start, stop in _blocks(ticks):
        block = zip(
            states[start:stop],
            row_log[start:stop],
            measurements[start:stop],
            angles[start:stop],
            slips[start:stop],
            windows[start:stop],
            command_log[start:stop],
            delayed[start:stop],
            flange_log[start:stop],
            strict=True,
        )
        for state, row, measurement, angle, slip, recent, command, applied, position in block:
            sense(model, data, state, signature)
            dot(measure, row, out=measurement)
            if quantised:
                rint(angle, out=angle)
            dot(pd_law, recent, out=command)
            copy(ctrl, applied)
            if opposing is not None:
                tanh(slip, out=slip)
                multiply(slip, opposing, out=motor_force)
            step(model, data)
            copy(position, flange)
            if remaining_substeps:
                step(model, data, remaining_substeps)
        if stopped := _stopped(plant, states, reference, start, stop):
            return stopped
    return ticks, ""


@dataclass(frozen=True)
class _Sensing:
    """How the loop turns a row (qpos, qvel, noise, feed-forward) into its command.

    A measurement is (fed-back angles [and their velocities, if exact], θ̇ / smoothing,
    feed-forward); with encoders the angles are noisy counts and the velocity the mean of their
    differences over `window` ticks, folded into `pd_law`.
    """

    encoders: Encoders
    measure: np.ndarray  # (width, nx + 14): a tick's measurement = measure @ row
    pd_law: np.ndarray  # (7, width · (window + 1)): the command = pd_law @ recent measurements
    window: int  # rows of past measurements the PD law reads besides the current one
    quantised: bool
    slip: slice  # where θ̇ / smoothing sits in a measurement

    @property
    def width(self) -> int:
        return len(self.measure)

    @classmethod
    def of(cls, plant: Plant, controller: PDController) -> "_Sensing":
        n, nq, nx = len(JOINT_NAMES), plant.model.nq, plant.model.nq + plant.model.nv
        spec = plant.spec
        encoders = Encoders(spec.sensors)
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
        """(ticks, nx + 14) rows with the noise and feed-forward filled in, the state to come."""
        n, nx = len(JOINT_NAMES), plant.model.nq + plant.model.nv
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
            rest[: len(JOINT_NAMES)] = self.encoders.counts(plant.feedback_map @ plant.data.qpos)
        return rest


def _exact_readings(plant: Plant, state: np.ndarray, applied: np.ndarray) -> dict[str, np.ndarray]:
    """The log's sensor columns when the sensors are exact: the simulator's state as is."""
    qpos, qvel = np.split(state, [plant.model.nq], axis=1)
    return {
        "q": qpos @ plant.link_map.T,
        "qd": qvel @ plant.link_map.T,
        "tau": _joint_torque(plant, qpos, qvel, applied),
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
    torque = _joint_torque(plant, qpos, qvel, applied)
    torque_noise = noise(spec.sensors, TORQUE, ticks, spec.sensors.torque_noise)
    return {
        "q": readings["link"][0],
        "qd": readings["link"][1],
        "tau": torque + torque_noise,
        "u": applied,
        "theta": readings["motor"][0],
        "theta_d": readings["motor"][1],
    }


def _joint_torque(
    plant: Plant, qpos: np.ndarray, qvel: np.ndarray, applied: np.ndarray
) -> np.ndarray:
    """What the joint torque sensors measure: the spring torque of an elastic joint; for a rigid
    one, the applied torque less the motor's friction."""
    if plant.elastic:
        return plant.joint_torque(qpos, qvel)
    return applied - friction_torque(plant.spec.friction, qvel @ plant.motor_map.T)


def _blocks(ticks: int) -> Iterator[tuple[int, int]]:
    """(start, stop) of the blocks of ticks a loop runs between two divergence checks."""
    for start in range(0, ticks, CHECK_EVERY):
        yield start, min(start + CHECK_EVERY, ticks)


def _stopped(
    plant: Plant, states: np.ndarray, reference: Reference, start: int, stop: int
) -> tuple[int, str] | None:
    """(ticks kept, why) if the episode diverged in ticks [start, stop), else None."""
    bad_tick, reason = _first_divergence(plant, states[start:stop], reference.q[start:stop])
    if bad_tick is None:
        return None
    tick = start + bad_tick
    return tick, f"{reason} at t = {tick * CONTROL_PERIOD:.3f} s"


def _first_divergence(plant: Plant, state: np.ndarray, q_des: np.ndarray) -> tuple[int | None, str]:
    """First tick of a block where the state is non-finite, out of range or lost, and why."""
    finite = np.isfinite(state).all(axis=1)
    with np.errstate(invalid="ignore"):
        q = state[:, : plant.model.nq] @ plant.link_map.T
        out_of_range = (q < plant.joint_range[:, 0]) | (q > plant.joint_range[:, 1])
        lost = np.abs(q - q_des) > MAX_JOINT_ERROR
    checks = (
        (~finite, "the simulation became non-finite"),
        (out_of_range.any(axis=1), "a joint left its range"),
        (lost.any(axis=1), f"a joint error exceeded {MAX_JOINT_ERROR} rad"),
    )
    first: tuple[int | None, str] = (None, "")
    for flags, reason in checks:
        hits = np.flatnonzero(flags)
        if hits.size and (first[0] is None or hits[0] < first[0]):
            first = (int(hits[0]), reason)
    return first


@cache
def software_versions() -> dict[str, str]:
    return {
        "gainfarm": version("gainfarm"),
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }
