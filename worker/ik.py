"""System layer, part 2: joint positions that put the flange on a path with a given orientation.

Damped least squares on the 6-D pose error (position and orientation), with a posture term in
the Jacobian's null space (a 7-joint arm's elbow self-motion; a 6-joint arm has none) so that a
redundant degree of freedom settles at the point of the self-motion nearest a comfortable
posture. Each sample is warm-started from the previous ones and solved to convergence, not to a
loose tolerance: the solution is then a smooth function of the path, which its derivatives (the
reference's joint speeds and accelerations) need.
"""

import math
from functools import cache

import mujoco
import numpy as np

from gainfarm.models import compile_model, robot_of
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec

# The default robot's (the iiwa 14's) home: the ready posture, the flange pointing down over the
# workspace centre (each robot's is its `workspace.home`: `home`).
READY_POSTURE = np.array(robot_of().workspace.home)
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
# A first joint whose axis is within this of the vertical turns the whole arm about it (cos 2.6°).
VERTICAL = 0.999
# A heading is rounded to this many decimals of a radian: a home facing +x is exactly 0 whatever
# the last bits of its kinematics (far finer than any path's placement).
HEADING_DECIMALS = 9


class UnreachablePath(ValueError):
    """The path leaves the workspace the arm can reach within its joint limits."""


def kinematic_model(robot: str = DEFAULT_ROBOT) -> mujoco.MjModel:
    """The robot's rigid chain, one hinge per joint: kinematics do not depend on the elastic
    joints' numbers nor on the inertials, so this one model serves every plant of the robot."""
    sets = robot_of(robot).inertial_sets
    return compile_model(PlantSpec(robot=robot, joints="rigid", substeps=1, inertials=sets[0]))


def home(robot: str = DEFAULT_ROBOT) -> np.ndarray:
    """The robot's home posture (its workspace's), a fresh array."""
    return np.array(robot_of(robot).workspace.home, dtype=float)


def ready_posture(yaw: float = 0.0, robot: str = DEFAULT_ROBOT) -> np.ndarray:
    """The robot's home turned about the vertical so that the arm faces heading `yaw` (rad, from
    the base's x axis): the elbow faces the path.

    The rule holds for any serial arm whose first joint turns about the vertical (the iiwa's A1,
    the UR5e's shoulder pan, ...): turning that joint by Δ turns the whole arm by ±Δ (the sign
    of its axis), so it turns by the angle from the flange's heading at home to `yaw`. A heading
    the first joint cannot reach gets its furthest turn; an arm whose first axis is not vertical
    is left at home (the inverse kinematics then finds its own way).
    """
    posture = home(robot)
    sign, heading, reach = facing(robot)
    if sign == 0.0:
        return posture
    turn = math.remainder(yaw - heading, 2.0 * math.pi)  # the shorter way round
    posture[0] = np.clip(posture[0] + sign * turn, -reach, reach)
    return posture


@cache
def facing(robot: str) -> tuple[float, float, float]:
    """(the sign of the first joint's axis against the vertical, or 0 if it is not vertical;
    the flange's heading at home about that axis, rad; how far the first joint may turn, rad)."""
    model = kinematic_model(robot)
    arm = robot_of(robot)
    data = mujoco.MjData(model)
    data.qpos[:] = arm.workspace.home
    mujoco.mj_kinematics(model, data)
    axis, anchor = data.xaxis[0], data.xanchor[0]
    reach = arm.limits.position[0] - RANGE_MARGIN
    if abs(axis[2]) < VERTICAL:
        return 0.0, 0.0, reach
    offset = data.site_xpos[model.site(arm.flange).id] - anchor
    heading = round(math.atan2(offset[1], offset[0]), HEADING_DECIMALS) + 0.0
    return math.copysign(1.0, axis[2]), heading, reach


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
            # Damped pseudo-inverse for the task; the exact null space (the right singular
            # vectors past the 6th: one on a 7-joint arm, none on a 6-joint one) for the
            # posture, so the posture never pulls the flange off its pose.
            step = vt[:6].T @ ((sigma / (sigma**2 + DAMPING**2)) * (u.T @ error))
            for null in vt[6:]:
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
