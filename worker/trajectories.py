"""System layer, part 1: Cartesian end-effector paths sampled at the 500 Hz control rate.

Pure NumPy/SciPy: a spec in, an (n, 3) array of positions out. Every path is a curve p(s) for
s in [0, 1], traversed with minimum-jerk timing s(t), so the robot starts and ends at rest.
"""

import numpy as np
from scipy.interpolate import PchipInterpolator

from schemas.trajectory import CONTROL_PERIOD_NS, TrajectoryKind, TrajectorySpec


def sample_times(spec: TrajectorySpec) -> np.ndarray:
    """Tick times in s, computed from whole nanoseconds so that log times round-trip exactly."""
    return np.arange(spec.ticks) * CONTROL_PERIOD_NS / 1e9


def minimum_jerk(tau: np.ndarray) -> np.ndarray:
    """0 → 1 with zero velocity and acceleration at both ends."""
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def cartesian_path(spec: TrajectorySpec) -> np.ndarray:
    """End-effector positions (n, 3) in the base frame, one per control tick."""
    s = minimum_jerk(np.clip(sample_times(spec) / spec.duration, 0.0, 1.0))
    shape = _SHAPES[spec.kind]
    return np.asarray(spec.center) + shape(spec, s)


def _spiral(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """A conical helix: the radius grows from 0 to `size` while it rises by `size`."""
    angle = 2.0 * np.pi * spec.turns * s
    radius = spec.size * s
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), spec.size * (s - 0.5)])


def _random(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """A smooth curve through seeded waypoints drawn in a cube of half-width `size`.

    PCHIP rather than a cubic spline: it is C¹ and never overshoots its waypoints, so the
    path stays inside the cube the spec promises (and inside the reachable workspace).
    """
    rng = np.random.default_rng(spec.seed)
    points = rng.uniform(-spec.size, spec.size, size=(spec.waypoints, 3))
    # Chord-length knots keep the speed even between near and far waypoints.
    knots = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return PchipInterpolator(knots / knots[-1], points)(s)


def _pyramid(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """Around a square pyramid's edges (base half-width `size`, height `size`), at even speed."""
    h = spec.size / 2.0
    b0, b1, b2, b3 = ([sx * spec.size, sy * spec.size, -h] for sx, sy in _BASE_CORNERS)
    apex = [0.0, 0.0, h]
    vertices = np.array([b0, apex, b1, b2, apex, b3, b0])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(vertices, axis=0), axis=1))])
    target = s * arc[-1]
    return np.column_stack([np.interp(target, arc, vertices[:, axis]) for axis in range(3)])


_BASE_CORNERS = ((1, 1), (1, -1), (-1, -1), (-1, 1))
_SHAPES = {
    TrajectoryKind.spiral: _spiral,
    TrajectoryKind.random: _random,
    TrajectoryKind.pyramid: _pyramid,
}
