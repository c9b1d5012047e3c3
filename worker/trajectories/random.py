"""The random kind: a smooth B-spline shaped by seeded random control points in a cube."""

from functools import lru_cache

import numpy as np
from scipy.interpolate import BSpline

from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.trajectories import Kind

# The random kind's tightest turn, as a fraction of its size: a sharper one needs a slow path.
RANDOM_MIN_TURN_RADIUS = 0.3
_TURN_SAMPLES = 1025  # samples of a candidate random curve at which its curvature is measured
_RANDOM_BATCH = 256  # control polygons tested at once
_RANDOM_BATCHES = 32  # at most; if none turns gently enough, the gentlest one is taken


def random_path(spec: TrajectorySpec, u: np.ndarray) -> np.ndarray:
    """The random kind's Path: `_random`'s B-spline."""
    return _random(spec)(u)


def _random(spec: TrajectorySpec) -> BSpline:
    """A cubic B-spline shaped by seeded control points in the cube of half-width `size`.

    It starts at the first control point, ends at the last and is pulled toward the others. A
    B-spline rather than an interpolating spline: it is C² (so the arm needs no infinite
    acceleration anywhere) and it stays inside the control points' hull (so inside the cube the
    spec promises). Where random control points fold back on themselves even a B-spline can
    turn on the spot (a near-cusp), which no arm can follow at speed: such draws are rejected,
    and the seed's first curve whose tightest turn has a radius of at least
    RANDOM_MIN_TURN_RADIUS·size is the path.
    """
    degree = min(3, spec.waypoints - 1)
    inner = np.linspace(0.0, 1.0, spec.waypoints - degree + 1)
    knots = np.concatenate([np.zeros(degree), inner, np.ones(degree)])
    unit = _random_control_points(spec.seed, spec.waypoints, degree, tuple(knots))
    return BSpline(knots, spec.size * unit, degree)


@lru_cache(maxsize=64)
def _random_control_points(
    seed: int, count: int, degree: int, knots: tuple[float, ...]
) -> np.ndarray:
    """The seed's first control polygon in [-1, 1]³ whose curve turns gently enough.

    Candidates are drawn and tested in batches (the curve is linear in its control points, so
    one basis matrix serves them all); the draws, and so the choice, depend on the seed only.
    """
    rng = np.random.default_rng(seed)
    if degree < 2:  # a straight line never turns
        return rng.uniform(-1.0, 1.0, size=(count, 3))
    u = np.linspace(0.0, 1.0, _TURN_SAMPLES)
    basis = [BSpline(np.array(knots), np.eye(count), degree).derivative(n)(u) for n in (1, 2)]
    best, best_radius = None, -1.0
    for _ in range(_RANDOM_BATCHES):
        points = rng.uniform(-1.0, 1.0, size=(_RANDOM_BATCH, count, 3))
        d1, d2 = basis[0] @ points, basis[1] @ points  # (batch, samples, 3)
        speed = np.sqrt(np.sum(d1 * d1, axis=2))
        bend = np.sqrt(np.sum(_cross(d1, d2) ** 2, axis=2))
        radius = np.min(speed**3 / np.maximum(bend, 1e-300), axis=1)
        passed = np.flatnonzero(radius >= RANDOM_MIN_TURN_RADIUS)
        if len(passed):
            return points[passed[0]]
        if radius.max() > best_radius:
            best, best_radius = points[int(np.argmax(radius))], float(radius.max())
    return best


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross over the last axis, several times faster on large stacks."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


KIND = Kind(path=random_path)
