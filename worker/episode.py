"""One episode: the system, control and sensor/actuator layers stepping together at 500 Hz.

The tick loop is the hot path (thousands of episodes, thousands of ticks each): it only copies
the state into preallocated logs, evaluates the PD law as two 7x14 matrix-vector products and
steps the physics. Everything else (reference, feed-forward, kinematics of the log, divergence
checks) is done in bulk, once per episode or once per block of ticks.
"""

import platform
from importlib.metadata import version

import mujoco
import numpy as np

from schemas.episode import EpisodeMetadata, EpisodeSpec
from schemas.episode_log import EpisodeLog
from schemas.robot import JOINT_NAMES
from schemas.trajectory import CONTROL_PERIOD
from worker.control import PDController
from worker.plant import Plant
from worker.reference import Reference, reference_for

CHECK_EVERY = 50  # ticks between divergence checks (0.1 s): cheap, and early enough
MAX_JOINT_ERROR = 1.0  # rad: a tracking error this large is a lost arm, not a tuning trade-off


def run_episode(spec: EpisodeSpec) -> EpisodeLog:
    """Simulate `spec` and return its log. A diverging episode is stopped early and flagged."""
    reference = reference_for(spec.trajectory)
    plant = Plant(spec.model)
    controller = PDController.from_gains(spec.gains, plant.torque_limits)
    gravity = reference.gravity if spec.gravity_compensation else 0.0
    feedforward = controller.reference_term(reference.q, reference.qd, gravity)
    plant.reset(reference.q[0])

    ticks = len(reference.t)
    qpos = np.empty((ticks, plant.model.nq))
    qvel = np.empty((ticks, plant.model.nv))
    torque = np.empty((ticks, len(JOINT_NAMES)))
    ticks_run, divergence = _simulate(plant, controller, feedforward, reference, qpos, qvel, torque)

    q = qpos[:ticks_run] @ plant.link_map.T
    qd = qvel[:ticks_run] @ plant.link_map.T
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
        q=q,
        qd=qd,
        tau=torque[:ticks_run],
        q_des=reference.q[:ticks_run].copy(),
        qd_des=reference.qd[:ticks_run].copy(),
        ee=plant.flange_positions(qpos[:ticks_run]),
        ee_des=reference.ee[:ticks_run].copy(),
        metadata=metadata,
    )


def _simulate(
    plant: Plant,
    controller: PDController,
    feedforward: np.ndarray,
    reference: Reference,
    qpos_log: np.ndarray,
    qvel_log: np.ndarray,
    torque_log: np.ndarray,
) -> tuple[int, str]:
    """Run the tick loop; return (ticks kept in the logs, divergence reason or "")."""
    model, data, substeps = plant.model, plant.data, plant.substeps
    qpos, qvel, ctrl = data.qpos, data.qvel, data.ctrl
    kp_state, kd_state = controller.state_gains(plant.link_map)
    high = controller.torque_limits
    low = -high
    kp_term = np.empty(len(high))
    kd_term = np.empty(len(high))
    step = mujoco.mj_step
    ticks = len(feedforward)
    for start in range(0, ticks, CHECK_EVERY):
        stop = min(start + CHECK_EVERY, ticks)
        for k in range(start, stop):
            np.copyto(qpos_log[k], qpos)
            np.copyto(qvel_log[k], qvel)
            u = torque_log[k]
            np.dot(kp_state, qpos, out=kp_term)
            np.dot(kd_state, qvel, out=kd_term)
            np.subtract(feedforward[k], kp_term, out=u)
            np.subtract(u, kd_term, out=u)
            np.minimum(u, high, out=u)
            np.maximum(u, low, out=u)
            np.copyto(ctrl, u)
            step(model, data, substeps)
        bad_tick, reason = _first_divergence(
            plant, qpos_log[start:stop], qvel_log[start:stop], reference.q[start:stop]
        )
        if bad_tick is not None:
            return start + bad_tick, f"{reason} at t = {(start + bad_tick) * CONTROL_PERIOD:.3f} s"
    return ticks, ""


def _first_divergence(
    plant: Plant, qpos: np.ndarray, qvel: np.ndarray, q_des: np.ndarray
) -> tuple[int | None, str]:
    """First tick of a block where the state is non-finite, out of range or lost, and why."""
    finite = np.isfinite(qpos).all(axis=1) & np.isfinite(qvel).all(axis=1)
    with np.errstate(invalid="ignore"):
        q = qpos @ plant.link_map.T
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


def software_versions() -> dict[str, str]:
    return {
        "gainfarm": version("gainfarm"),
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }
