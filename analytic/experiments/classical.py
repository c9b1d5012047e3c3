"""A baseline without a genetic algorithm: the textbook per-joint PD rule.

Each joint is taken alone, as a rigid inertia M_ii (the diagonal of the arm's mass matrix at the
ready posture, the rotor's reflected inertia included as the rigid model's armature) under
Kp (q* - q) + Kd (q̇* - q̇). Its closed loop M_ii q̈ + Kd q̇ + Kp q = 0 has natural frequency ω and
damping ratio ζ when

    Kp = ω² M_ii,    Kd = 2 ζ ω M_ii

(ζ = 1: critically damped; ζ = 0.7: the fastest settling without much overshoot). The rule gives
one controller per (ω, ζ) of a grid, all joints at the same ω; any gain outside the search space
(analytic.search_space) is clipped to its bound, and the controllers with a clipped gain are
counted, since they no longer follow the rule exactly. Everything here is pure apart from
`joint_inertias`, which asks MuJoCo for the mass matrix.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.models import compile_model, robot_of
from gainfarm.models.dynamics import rigid_spec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import PlantSpec

OMEGAS = (5.0, 10.0, 15.0, 20.0, 30.0, 40.0, 60.0, 80.0)  # rad/s: the default gains' are 29-60
DAMPINGS = (0.7, 1.0)


@dataclass(frozen=True)
class ClassicalGains:
    """The rule's controllers, one per (ω, ζ) in `settings`, and how many had a gain clipped."""

    gains: list[PDGains]
    settings: list[tuple[float, float]]  # (ω rad/s, ζ) of each controller, in order
    clipped: int


def joint_inertias(
    plant: PlantSpec | None = None, posture: Sequence[float] | None = None
) -> np.ndarray:
    """M_ii, kg·m², per joint: the diagonal of the mass matrix of `plant`'s rigid arm
    (models.dynamics.rigid_spec: rotor inertias as armature) at `posture` (default: the
    robot's home, its workspace's)."""
    plant = plant or PlantSpec()
    robot = robot_of(plant)
    joints = len(robot.joint_names)
    model = compile_model(rigid_spec(plant))
    data = mujoco.MjData(model)
    data.qpos[:joints] = robot.workspace.home if posture is None else posture
    mujoco.mj_forward(model, data)
    mass_matrix = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, mass_matrix)
    return np.diag(mass_matrix)[:joints].copy()


def rule(inertia: Sequence[float], omega: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """(Kp, Kd) per joint for natural frequency `omega` (rad/s) and damping ratio `zeta`."""
    m = np.asarray(inertia, dtype=float)
    return omega**2 * m, 2.0 * zeta * omega * m


def classical_gains(
    inertia: Sequence[float],
    omegas: Sequence[float] = OMEGAS,
    dampings: Sequence[float] = DAMPINGS,
    space: SearchSpace | None = None,
) -> ClassicalGains:
    """The rule's controller for every (ω, ζ) of the grid, ω-major, clipped to `space`."""
    space = space or SearchSpace()
    kp_low, kp_high = np.array(space.kp_low), np.array(space.kp_high)
    kd_low, kd_high = np.array(space.kd_low), np.array(space.kd_high)
    gains, settings, clipped = [], [], 0
    for omega in omegas:
        for zeta in dampings:
            kp, kd = rule(inertia, omega, zeta)
            kp_in, kd_in = np.clip(kp, kp_low, kp_high), np.clip(kd, kd_low, kd_high)
            clipped += int(not (np.array_equal(kp_in, kp) and np.array_equal(kd_in, kd)))
            gains.append(PDGains(kp=tuple(kp_in.tolist()), kd=tuple(kd_in.tolist())))
            settings.append((float(omega), float(zeta)))
    return ClassicalGains(gains, settings, clipped)


def classical_baseline(
    plant: PlantSpec | None = None,
    omegas: Sequence[float] = OMEGAS,
    dampings: Sequence[float] = DAMPINGS,
    space: SearchSpace | None = None,
) -> ClassicalGains:
    """The rule's controllers for `plant`'s arm at its home posture, clipped to `space`
    (default: the search space around the robot's default gains)."""
    plant = plant or PlantSpec()
    space = space or SearchSpace.around(robot_of(plant).default_gains)
    return classical_gains(joint_inertias(plant), omegas, dampings, space)
