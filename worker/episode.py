"""One episode: the system, control and sensor/actuator layers stepping together at 500 Hz.

The tick loop is the hot path (thousands of episodes, thousands of ticks each): it only copies
the state and flange position into preallocated logs, evaluates the PD law as one matrix-vector
product and steps the physics. Everything else (reference, feed-forward, torque clamping in the
log, divergence checks) is done in bulk, once per episode or once per block of ticks.
"""

import platform
from functools import cache
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

CHECK_EVERY = 250  # ticks between divergence checks (0.5 s): cheap, and early enough
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
    state = np.empty((ticks, plant.model.nq + plant.model.nv))
    torque = np.empty((ticks, len(JOINT_NAMES)))
    flange = np.empty((ticks, 3))
    ticks_run, divergence = _simulate(
        plant, controller, feedforward, reference, state, torque, flange
    )

    # MuJoCo clamped each command to the motor's ctrlrange (the torque limit) when applying it;
    # clamping is exact, so doing the same here in bulk logs exactly the torques applied.
    applied = np.clip(torque[:ticks_run], -plant.torque_limits, plant.torque_limits)
    qpos, qvel = np.split(state[:ticks_run], [plant.model.nq], axis=1)
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
        q=qpos @ plant.link_map.T,
        qd=qvel @ plant.link_map.T,
        tau=applied,
        q_des=reference.q[:ticks_run].copy(),
        qd_des=reference.qd[:ticks_run].copy(),
        ee=flange[:ticks_run],
        ee_des=reference.ee[:ticks_run].copy(),
        metadata=metadata,
    )


def _simulate(
    plant: Plant,
    controller: PDController,
    feedforward: np.ndarray,
    reference: Reference,
    state_log: np.ndarray,
    torque_log: np.ndarray,
    flange_log: np.ndarray,
) -> tuple[int, str]:
    """Run the tick loop; return (ticks kept in the logs, divergence reason or "").

    Each tick: sense the state, set the PD command, take the first physics step, then log the
    flange position (mj_step computes kinematics before it integrates, so site_xpos is still this
    tick's), then take the remaining substeps. The command is logged unclamped; see run_episode.
    """
    model, data = plant.model, plant.data
    ctrl, flange = data.ctrl, data.site_xpos[plant.flange]
    kp_state, kd_state = controller.state_gains(plant.link_map)
    state_gain = np.hstack([kp_state, kd_state])  # Kp q + Kd q̇ = state_gain @ (qpos, qvel)
    feedback = np.empty(len(controller.kp))
    sense, signature = (
        mujoco.mj_getState,
        mujoco.mjtState.mjSTATE_QPOS | mujoco.mjtState.mjSTATE_QVEL,
    )
    step = mujoco.mj_step
    remaining_substeps = plant.substeps - 1
    dot, subtract, copy = np.dot, np.subtract, np.copyto
    ticks = len(feedforward)
    for start in range(0, ticks, CHECK_EVERY):
        stop = min(start + CHECK_EVERY, ticks)
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
        bad_tick, reason = _first_divergence(plant, state_log[start:stop], reference.q[start:stop])
        if bad_tick is not None:
            return start + bad_tick, f"{reason} at t = {(start + bad_tick) * CONTROL_PERIOD:.3f} s"
    return ticks, ""


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
