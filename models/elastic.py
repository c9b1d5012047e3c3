"""Whether MuJoCo integrates an arm's elastic joints well at a physics step: for any robot.

An elastic joint is two coaxial hinges in the link's body (models/iiwa14.py explains the model):
`J_motor`, the rotor's side, and `J_spring`, the deflection, of stiffness K and damping D.
MuJoCo integrates joint stiffness explicitly and joint damping implicitly. For one spring on an
effective inertia m, its step dt is stable while K dt² < 4 m + 2 D dt (with D = 0: ω·dt < 2).
Requiring a quarter of that bound keeps it well inside (with D = 0: ω·dt ≤ 1, a frequency error
under 5 %). The iiwa 14 keeps its own copy of these functions (models/iiwa14.py), tied to its
joint names and postures; this module takes the arm's.
"""

from collections.abc import Sequence

import mujoco
import numpy as np

from gainfarm.schemas.trajectory import CONTROL_PERIOD

MAX_STEP_RATIO = 0.25


def motor(joint: str) -> str:
    """The motor-side hinge of `joint` in the flexible model (the name the worker reads)."""
    return f"{joint}_motor"


def spring(joint: str) -> str:
    """The deflection hinge of `joint` in the flexible model (the name the worker reads)."""
    return f"{joint}_spring"


def effective_inertias(
    model: mujoco.MjModel, joints: Sequence[str], postures: Sequence[Sequence[float]]
) -> np.ndarray:
    """Per joint, the inertia its spring turns, kg·m²: the link side's against the rotor's,
    I B / (I + B), from the mass matrix of the flexible `model` with every other joint held; the
    smallest of its values at `postures` (motor angles, springs relaxed)."""
    motors = np.array([model.joint(motor(name)).id for name in joints])
    springs = np.array([model.joint(spring(name)).id for name in joints])
    m_dof, s_dof = model.jnt_dofadr[motors], model.jnt_dofadr[springs]
    data = mujoco.MjData(model)
    mass_matrix = np.zeros((model.nv, model.nv))
    inertia = np.full(len(joints), np.inf)
    for posture in postures:
        data.qpos[:] = 0.0
        data.qpos[model.jnt_qposadr[motors]] = posture
        mujoco.mj_forward(model, data)
        mujoco.mj_fullM(model, data, mass_matrix)
        coupling = mass_matrix[m_dof, s_dof]
        # The spring's Schur complement: the motor hinge turns with it, the other joints held.
        schur = mass_matrix[s_dof, s_dof] - coupling**2 / mass_matrix[m_dof, m_dof]
        # Without a rotor (B = 0) the spring turns nothing: zero, not a rounding error's residue.
        schur[schur <= 1e-12 * mass_matrix[s_dof, s_dof]] = 0.0
        inertia = np.minimum(inertia, schur)
    return inertia


def step_ratios(
    stiffness: Sequence[float], damping: Sequence[float], inertia: np.ndarray, dt: float
) -> np.ndarray:
    """Per joint, K dt² / (4 m + 2 D dt): stable below 1, well integrated at most
    MAX_STEP_RATIO."""
    k, d = np.asarray(stiffness, dtype=float), np.asarray(damping, dtype=float)
    return k * dt**2 / (4 * inertia + 2 * d * dt)


def min_substeps(
    stiffness: Sequence[float],
    damping: Sequence[float],
    inertia: np.ndarray,
    joints: Sequence[str],
) -> int:
    """The fewest physics steps per control tick that integrate the springs well (every joint's
    step ratio at most MAX_STEP_RATIO)."""
    k, d = np.asarray(stiffness, dtype=float), np.asarray(damping, dtype=float)
    # The longest step with K dt² = MAX_STEP_RATIO (4 m + 2 D dt): the quadratic's positive root.
    a, b = MAX_STEP_RATIO * 2 * d, MAX_STEP_RATIO * 4 * inertia
    longest = (a + np.sqrt(a**2 + 4 * k * b)) / (2 * k)
    if not longest.min() > 0:
        joint = joints[int(longest.argmin())]
        raise ValueError(f"{joint}'s spring turns no inertia and has no damping: no step fits it")
    substeps = max(1, int(np.ceil(CONTROL_PERIOD / longest.min())))
    while step_ratios(k, d, inertia, CONTROL_PERIOD / substeps).max() > MAX_STEP_RATIO:
        substeps += 1  # only ever rounding at the boundary
    return substeps


def check_substeps(
    substeps: int,
    stiffness: Sequence[float],
    damping: Sequence[float],
    inertia: np.ndarray,
    joints: Sequence[str],
) -> None:
    """Raise ValueError, in one line, if `substeps` is too few for the springs."""
    ratios = step_ratios(stiffness, damping, inertia, CONTROL_PERIOD / substeps)
    if ratios.max() <= MAX_STEP_RATIO:
        return
    worst = int(ratios.argmax())
    raise ValueError(
        f"substeps={substeps} is too few for {joints[worst]}'s joint spring "
        f"(K = {stiffness[worst]:g} N·m/rad): this plant needs substeps >= "
        f"{min_substeps(stiffness, damping, inertia, joints)}"
    )
