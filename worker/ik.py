"""System layer, part 2: joint positions that put the flange on a path with a given orientation.

Damped least squares on the 6-D pose error (position and orientation), with a posture term in the
Jacobian's one-dimensional null space (the elbow's self-motion) so that the redundant degree of
freedom settles at the point of the self-motion nearest a comfortable posture. Each sample is
warm-started from the previous ones and solved to convergence, not to a loose tolerance: the
solution is then a smooth function of the path, which its derivatives (the reference's joint
speeds and accelerations) need.
"""

import mujoco
import numpy as np

from gainfarm.models import robot_of

# The default robot's (the iiwa 14's) home: the ready posture, the flange pointing down over the
# workspace centre. A reference is of the default robot's until the plant's is passed (issue 49).
_ROBOT = robot_of()
READY_POSTURE = np.array(_ROBOT.workspace.home)
DAMPING = 1e-2  # λ of the damped pseudo-inverse: only matters near singular postures
POSTURE_GAIN = 1.0  # the full step to the self-motion's point nearest the posture, per iteration
MAX_STEP = 0.2  # rad per iteration: keeps the first, far-from-posture solve on its branch
STEP_TOLERANCE = 1e-11  # rad: converged; far below what the splines of the solution resolve
# Guaranteed bounds on the flange's pose error, checked at every IK sample here and again at
# every control tick of a reference (worker/reference.py): worse is refused as unreachable.
# Converged solutions are some 1e-8 m and 1e-9 rad off.
REACH_TOLERANCE = 1e-4  # m
ORIENTATION_TOLERANCE = 1e-3  # rad
RANGE_MARGIN = 0.05  # rad kept clear of each joint's mechanical limit
MAX_ITERATIONS = 50
FIRST_SAMPLE_ITERATIONS = 500
_A1_RANGE = _ROBOT.limits.position[0]


class UnreachablePath(ValueError):
    """The path leaves the workspace the arm can reach within its joint limits."""


def ready_posture(yaw: float = 0.0) -> np.ndarray:
    """The ready posture turned about the vertical by `yaw` (A1): the elbow faces the path.

    A path behind the robot (A1 cannot turn the last 10° to face it) gets A1's furthest turn.
    """
    posture = READY_POSTURE.copy()
    posture[0] = np.clip(yaw, -_A1_RANGE + RANGE_MARGIN, _A1_RANGE - RANGE_MARGIN)
    return posture


def orientation_error(rotation: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) from `rotation` to `desired` (3×3 each), in the base frame, rad.

    The exact logarithm: its norm is the angle between the two frames.
    """
    relative = desired @ rotation.T
    vee = 0.5 * np.array(
        [
            relative[2, 1] - relative[1, 2],
            relative[0, 2] - relative[2, 0],
            relative[1, 0] - relative[0, 1],
        ]
    )
    sin = np.linalg.norm(vee)
    cos = 0.5 * (np.trace(relative) - 1.0)
    angle = np.arctan2(sin, cos)
    return vee * (angle / sin) if sin > 1e-12 else vee


def solve_path(
    model: mujoco.MjModel,
    site: str,
    positions: np.ndarray,
    rotations: np.ndarray,
    posture: np.ndarray = READY_POSTURE,
    progress: np.ndarray | None = None,
) -> np.ndarray:
    """Joint positions (n, nq) that put `site` at `positions` (n, 3) with `rotations` (n, 3, 3).

    `model` must be a kinematic chain with one hinge per joint (the rigid variant). `progress`
    (n,), the path's progress at each sample, only makes the error message say where it failed.
    """
    data = mujoco.MjData(model)
    site_id = model.site(site).id
    low = model.jnt_range[:, 0] + RANGE_MARGIN
    high = model.jnt_range[:, 1] - RANGE_MARGIN
    jac = np.zeros((6, model.nv))
    error = np.zeros(6)
    solution = np.empty((len(positions), model.nq))
    q = posture.copy()
    for k, (position, rotation) in enumerate(zip(positions, rotations, strict=True)):
        if k >= 2:
            # Linear extrapolation: the next solution is within O(Δs²) of it, so it converges
            # in a few iterations.
            q = np.clip(2.0 * solution[k - 1] - solution[k - 2], low, high)
        iterations = FIRST_SAMPLE_ITERATIONS if k == 0 else MAX_ITERATIONS
        for _ in range(iterations):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            error[:3] = position - data.site_xpos[site_id]
            error[3:] = orientation_error(data.site_xmat[site_id].reshape(3, 3), rotation)
            mujoco.mj_jacSite(model, data, jac[:3], jac[3:], site_id)
            u, sigma, vt = np.linalg.svd(jac)
            # Damped pseudo-inverse for the task; the exact null space (the 7th right singular
            # vector) for the posture, so the posture never pulls the flange off its pose.
            step = vt[:6].T @ ((sigma / (sigma**2 + DAMPING**2)) * (u.T @ error))
            null = vt[6]
            step += POSTURE_GAIN * null * (null @ (posture - q))
            norm = np.linalg.norm(step)
            if norm > MAX_STEP:
                step *= MAX_STEP / norm
            q = np.clip(q + step, low, high)
            if norm < STEP_TOLERANCE:
                break
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        miss = float(np.linalg.norm(position - data.site_xpos[site_id]))
        turn = float(
            np.linalg.norm(orientation_error(data.site_xmat[site_id].reshape(3, 3), rotation))
        )
        if miss > REACH_TOLERANCE or turn > ORIENTATION_TOLERANCE:
            where = f" at {100 * progress[k]:.0f} % of the path" if progress is not None else ""
            stuck = [model.joint(j).name for j in range(model.nq) if q[j] in (low[j], high[j])]
            why = f" ({', '.join(stuck)} at the end of its range)" if stuck else ""
            raise UnreachablePath(
                f"the path is unreachable{where}: the pose at {np.round(position, 3).tolist()} "
                f"is missed by {miss * 1000:.1f} mm and {np.degrees(turn):.2f}°{why}"
            )
        solution[k] = q
    return solution
