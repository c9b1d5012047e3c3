"""The fourier kind: every joint moves by a seeded finite Fourier series around the robot's home
posture, the identification standard, given directly in joint space and always feasible (it
scales itself into the robot's limits at any duration), for any number of joints."""

import math

import mujoco
import numpy as np

from gainfarm.schemas.robot import Robot
from gainfarm.schemas.trajectory import MIN_DURATION, TrajectorySpec
from gainfarm.worker.ik import kinematic_model
from gainfarm.worker.trajectories import Kind

# The share of each joint's speed and acceleration limit it may use, its largest excursion from
# the ready posture, its clearance from the joint ranges, and the lowest height the flange may
# reach (the robot stands on the floor, z = 0).
FOURIER_SHARE = 0.85
FOURIER_SPAN = 1.0  # rad
FOURIER_RANGE_MARGIN = 0.1  # rad
FOURIER_FLOOR = 0.1  # m
_FOURIER_SHRINK = 0.9  # per try, until the flange clears the floor
# Samples of the episode's fraction at which the series' peaks are found (as
# worker.reference.LIMIT_SAMPLES: finer than the control ticks of any duration up to 20 s).
_PEAK_SAMPLES = 10001


def fourier_coefficients(spec: TrajectorySpec, joints: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded sine and cosine coefficients (joints, harmonics), before any scaling to limits.

    The per-joint finite Fourier series is the standard excitation for identification (Swevers,
    Ganseman, Tukel, De Schutter and Van Brussel, IEEE Trans. Robotics and Automation 1997);
    Gaz et al. (IEEE RA-L 2019) use 5 harmonics of a 0.075 Hz base frequency. Here the base
    frequency is 1/duration, one period per episode: a 13.33 s episode is exactly Gaz's 0.075 Hz.

    The series q(τ) = Σ_k a_k sin(2πkτ) + b_k (cos(2πkτ) − 1) over the episode's fraction τ = t/T
    starts at zero; it starts and ends at rest when Σ k a_k = 0 (velocity) and Σ k² b_k = 0
    (acceleration), so the drawn coefficients are projected onto those two planes (the nearest
    coefficients that satisfy them). Drawing harmonic k with a 1/k spread keeps the higher
    harmonics from dominating the accelerations, as in optimised excitations.
    """
    rng = np.random.default_rng([spec.seed, 0xF0])  # not the random kind's stream for this seed
    k = np.arange(1, spec.harmonics + 1, dtype=float)
    a = rng.standard_normal((joints, spec.harmonics)) / k
    b = rng.standard_normal((joints, spec.harmonics)) / k
    a -= np.outer(a @ k, k) / (k @ k)
    b -= np.outer(b @ k**2, k**2) / (k**2 @ k**2)
    return a, b


def fourier_series(
    a: np.ndarray, b: np.ndarray, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The series and its first two derivatives in τ, each (len(tau), joints)."""
    k = np.arange(1, a.shape[1] + 1, dtype=float)
    phase = 2.0 * np.pi * np.outer(tau, k)
    sin, cos = np.sin(phase), np.cos(phase)
    w = 2.0 * np.pi * k
    position = sin @ a.T + (cos - 1.0) @ b.T
    velocity = (cos * w) @ a.T - (sin * w) @ b.T
    acceleration = -(sin * w**2) @ a.T - (cos * w**2) @ b.T
    return position, velocity, acceleration


def motion(
    spec: TrajectorySpec, t: np.ndarray, robot: Robot
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, qd, qdd at the times `t` on `robot`: the seeded series, each joint scaled to its
    binding limit.

    One period per episode (base frequency 1/duration). Each joint's amplitude is the largest
    that keeps it within FOURIER_SHARE of its speed and acceleration limits, FOURIER_SPAN of the
    robot's home posture and FOURIER_RANGE_MARGIN inside its range; then all joints shrink
    together until the flange stays FOURIER_FLOOR above the floor.
    """
    home = np.array(robot.workspace.home, dtype=float)
    limits = robot.limits
    speed, acceleration = (
        np.array(values, dtype=float) for values in (limits.speed, limits.acceleration)
    )
    model = kinematic_model(robot.name)
    low, high = model.jnt_range[:, 0], model.jnt_range[:, 1]  # its hinges' (need not be ±)
    a, b = fourier_coefficients(spec, len(robot.joint_names))
    x, dx, ddx = fourier_series(a, b, np.linspace(0.0, 1.0, _PEAK_SAMPLES))
    room_up = np.minimum(FOURIER_SPAN, high - FOURIER_RANGE_MARGIN - home)
    room_down = np.minimum(FOURIER_SPAN, -low - FOURIER_RANGE_MARGIN + home)
    tiny = np.finfo(float).tiny
    duration = spec.duration
    scale = np.min(
        [
            room_up / np.maximum(x.max(axis=0), tiny),
            room_down / np.maximum(-x.min(axis=0), tiny),
            FOURIER_SHARE * speed * duration / np.maximum(np.abs(dx).max(axis=0), tiny),
            FOURIER_SHARE * acceleration * duration**2 / np.maximum(np.abs(ddx).max(axis=0), tiny),
        ],
        axis=0,
    )
    x, dx, ddx = fourier_series(a, b, np.clip(t / duration, 0.0, 1.0))
    data = mujoco.MjData(model)
    site = model.site(robot.flange).id
    while True:
        q = home + x * scale
        if _lowest(model, data, site, q) >= FOURIER_FLOOR:
            break
        scale = scale * _FOURIER_SHRINK
    return q, dx * (scale / duration), ddx * (scale / duration**2)


def _lowest(model: mujoco.MjModel, data: mujoco.MjData, site: int, q: np.ndarray) -> float:
    lowest = math.inf
    for qk in q:
        data.qpos[:] = qk
        mujoco.mj_kinematics(model, data)
        lowest = min(lowest, float(data.site_xpos[site, 2]))
    return lowest


def shortest(spec: TrajectorySpec) -> float:
    """Any duration: the series scales itself into the limits."""
    return MIN_DURATION


KIND = Kind(joint_motion=motion, shortest_duration=shortest)
