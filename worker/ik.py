"""System layer, part 2: joint-space reference from a Cartesian path by inverse kinematics.

Damped least squares on the flange position, with a posture term in the Jacobian's null space so
that the redundant seventh degree of freedom stays near a comfortable posture, warm-started from
the previous sample so that consecutive solutions are continuous.
"""

import mujoco
import numpy as np

from schemas.trajectory import CONTROL_PERIOD

# A ready posture with the flange pointing down over the workspace centre (0.55, 0, 0.40).
READY_POSTURE = np.array([0.0, 0.5, 0.0, -1.6, 0.0, 1.0, 0.0])
DAMPING = 1e-2  # λ of the damped pseudo-inverse, m
POSTURE_GAIN = 0.05  # pull toward the posture per iteration, inside the null space
TOLERANCE = 1e-5  # m: well below any tracking error worth measuring
REACH_TOLERANCE = 1e-3  # m: a sample solved worse than this is unreachable
RANGE_MARGIN = 0.05  # rad kept clear of each joint's mechanical limit
MAX_ITERATIONS = 50
FIRST_SAMPLE_ITERATIONS = 500


class UnreachablePath(ValueError):
    """The path leaves the workspace the arm can reach within its joint limits."""


def solve_path(
    model: mujoco.MjModel,
    site: str,
    targets: np.ndarray,
    posture: np.ndarray = READY_POSTURE,
) -> np.ndarray:
    """Joint positions (n, nq) that put `site` on each of `targets` (n, 3).

    `model` must be a kinematic chain with one hinge per joint (the rigid variant).
    """
    data = mujoco.MjData(model)
    site_id = model.site(site).id
    low = model.jnt_range[:, 0] + RANGE_MARGIN
    high = model.jnt_range[:, 1] - RANGE_MARGIN
    jac = np.zeros((3, model.nv))
    eye = np.eye(model.nv)
    solution = np.empty((len(targets), model.nq))
    q = posture.copy()
    for k, target in enumerate(targets):
        iterations = FIRST_SAMPLE_ITERATIONS if k == 0 else MAX_ITERATIONS
        for _ in range(iterations):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            error = target - data.site_xpos[site_id]
            if error @ error < TOLERANCE**2:
                break
            mujoco.mj_jacSite(model, data, jac, None, site_id)
            pinv = jac.T @ np.linalg.inv(jac @ jac.T + DAMPING**2 * np.eye(3))
            step = pinv @ error + (eye - pinv @ jac) @ (POSTURE_GAIN * (posture - q))
            q = np.clip(q + step, low, high)
        residual = float(np.linalg.norm(error))
        if residual > REACH_TOLERANCE:
            raise UnreachablePath(
                f"the path is unreachable: at t = {k * CONTROL_PERIOD:.3f} s the point "
                f"{np.round(target, 3).tolist()} is missed by {residual * 1000:.1f} mm"
            )
        solution[k] = q
    return solution
