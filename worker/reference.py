"""System layer, part 3: the joint-space reference an episode tracks, computed once per spec.

The same trajectory is simulated thousands of times with different gains, so the inverse
kinematics runs once per spec and the result is cached in the worker process.
"""

from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np

from models import FLANGE, compile_model
from schemas.robot import ModelSpec
from schemas.trajectory import CONTROL_PERIOD, TrajectorySpec
from worker.ik import solve_path
from worker.trajectories import cartesian_path, sample_times

# Kinematics and gravity do not depend on the elastic-joint parameters: the rigid chain serves all.
_KINEMATIC_MODEL = ModelSpec(joints="rigid", substeps=1)


@dataclass(frozen=True)
class Reference:
    """Desired motion, one row per control tick. Arrays are read-only: the cache shares them."""

    t: np.ndarray  # (n,) s
    ee: np.ndarray  # (n, 3) desired flange position, m
    q: np.ndarray  # (n, 7) rad
    qd: np.ndarray  # (n, 7) rad/s
    gravity: np.ndarray  # (n, 7) N·m holding q against gravity, for optional compensation


@lru_cache(maxsize=64)
def reference_for(spec: TrajectorySpec) -> Reference:
    """The joint-space reference for `spec`; raises UnreachablePath if the arm cannot follow it."""
    model = compile_model(_KINEMATIC_MODEL)
    ee = cartesian_path(spec)
    q = solve_path(model, FLANGE, ee)
    qd = np.gradient(q, CONTROL_PERIOD, axis=0)
    reference = Reference(sample_times(spec), ee, q, qd, _gravity_torques(model, q))
    for array in (reference.t, reference.ee, reference.q, reference.qd, reference.gravity):
        array.flags.writeable = False
    return reference


def _gravity_torques(model: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(model)
    torques = np.empty_like(q)
    for k, qk in enumerate(q):
        data.qpos[:] = qk
        mujoco.mj_forward(model, data)  # qvel = 0, so the bias force is gravity alone
        torques[k] = data.qfrc_bias
    return torques
