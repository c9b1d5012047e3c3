"""System layer, part 1: what the arm is asked to do, before any kinematics.

Pure NumPy/SciPy. The Cartesian kinds are geometric paths: the flange's position p(s) and
orientation R(s) as functions of the path's progress s in [0, 1] (its arc-length fraction), with
the points where the arm comes to rest (`rest_points`). worker/reference.py turns them into
joint paths by inverse kinematics and times each rest-to-rest piece with the minimum-jerk law
within the robot's limits. The fourier kind is a joint-space motion given directly in time.

A trajectory kind of the gainfarm.trajectories plug-in group is a Cartesian path (`Path`), as
the spiral and the random kind are: the worker finds it by its name (gainfarm.plugins.load), and
a worker without it refuses the job (worker/job.py).
"""

from collections.abc import Callable
from functools import lru_cache
from typing import Protocol

import numpy as np
from scipy.interpolate import BSpline, CubicSpline

from gainfarm import plugins
from gainfarm.schemas.trajectory import CONTROL_PERIOD_NS, TrajectoryKind, TrajectorySpec

# The built-in Cartesian kinds; a plug-in's kind is Cartesian too.
CARTESIAN_KINDS = (TrajectoryKind.spiral, TrajectoryKind.random, TrajectoryKind.pyramid)
# The flange frame pointing straight down (columns: its x, y, z axes in the base frame): the
# ready posture's frame (worker/ik.py) once its 2.4° tilt is removed, so A7 starts near zero.
TOOL_DOWN = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
_ARC_SAMPLES = 4097  # dense samples of a curve to measure its arc length and its curvature
# The random kind's tightest turn, as a fraction of its size: a sharper one needs a slow path.
RANDOM_MIN_TURN_RADIUS = 0.3
_TURN_SAMPLES = 1025  # samples of a candidate random curve at which its curvature is measured
_RANDOM_BATCH = 256  # control polygons tested at once
_RANDOM_BATCHES = 32  # at most; if none turns gently enough, the gentlest one is taken
_FIBONACCI = 11400714819323198485  # ⌊2⁶⁴/φ⌋, odd: Knuth's multiplicative hashing constant
# How far a seed turns the spiral and the pyramid, in turns (`placed`): the spiral any way; the
# pyramid by ±30° at most, as beyond about 40° its edges lead the arm where the paper's 3 s
# path is too fast for it (3.3 s needed at 90°, measured by worker/reference.py).
SEED_TURNS = {TrajectoryKind.spiral: 1.0, TrajectoryKind.pyramid: 1.0 / 6.0}


def sample_times(spec: TrajectorySpec) -> np.ndarray:
    """Tick times in s, computed from whole nanoseconds so that log times round-trip exactly."""
    return np.arange(spec.ticks) * CONTROL_PERIOD_NS / 1e9


def minimum_jerk(tau: np.ndarray) -> np.ndarray:
    """0 → 1 with zero velocity and acceleration at both ends."""
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def minimum_jerk_derivatives(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """φ(τ), φ'(τ) and φ''(τ) of the minimum-jerk law, for analytic time derivatives."""
    return (
        minimum_jerk(tau),
        30.0 * tau**2 * (1.0 - tau) ** 2,
        60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau),
    )


# --- Cartesian paths ------------------------------------------------------------------------


class Path(Protocol):
    """A Cartesian trajectory kind, as a plug-in gives it (the spiral and the random kind are
    two): the flange's offsets from the spec's centre, (len(u), 3) in m, at the curve's
    parameter `u` (an array of values in [0, 1]). The curve is smooth (twice continuously
    differentiable: the arm's accelerations follow its curvature) and the arm rests at both of
    its ends; any parametrisation will do, the worker takes it by arc length and times it with
    the minimum-jerk law. The tool points down with the spec's twist about it. It may read the
    spec's size, seed, turns and waypoints; a path the arm cannot reach, or follow within its
    limits in the spec's duration, is refused (worker/reference.py) as the built-in kinds' are.
    """

    def __call__(self, spec: TrajectorySpec, u: np.ndarray) -> np.ndarray: ...


def path_points(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """Flange positions (m, 3) in the base frame at the path's progress `s` (arc fraction).
    PluginError if the spec's kind is a plug-in this process does not have."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    if spec.kind == TrajectoryKind.pyramid:
        offsets = pyramid(spec, s)
    elif spec.kind == TrajectoryKind.fourier:
        raise ValueError(f"the {spec.kind} kind is defined in joint space, not as a path")
    else:  # the spiral, the random kind or a plug-in's: a curve, taken by arc length
        offsets = _by_arc_length(_curve(spec))(s)
    return np.asarray(spec.center) + offsets


def _curve(spec: TrajectorySpec) -> Callable[[np.ndarray], np.ndarray]:
    """The kind's Path for this spec, u → offsets, checked: a plug-in's is a stranger's code."""
    path: Path = plugins.load(plugins.TRAJECTORIES, spec.kind)

    def curve(u: np.ndarray) -> np.ndarray:
        points = np.asarray(path(spec, u), dtype=float)
        if points.shape != (len(u), 3) or not np.all(np.isfinite(points)):
            raise ValueError(
                f"trajectory kind {spec.kind!r}: its path gave {points.shape} values, not "
                f"({len(u)}, 3) finite ones"
            )
        return points

    return curve


def rest_points(spec: TrajectorySpec) -> np.ndarray:
    """Progress values where the arm is at rest: the ends, and the pyramid's corners.

    Between two of them the arm moves along one rest-to-rest minimum-jerk segment.
    """
    if spec.kind == TrajectoryKind.pyramid:
        arc = _cumulative_length(_pyramid_vertices(spec))
        return arc / arc[-1]
    return np.array([0.0, 1.0])


def twist_angle(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """The tool's turn about its own axis (flange z, right-handed), rad, at progress `s`.

    twist·sin(2πs): zero at both ends, where the arm is at rest, and one full swing each way in
    between, so A7 turns by about 2·twist over every path.
    """
    return spec.twist * np.sin(2.0 * np.pi * np.asarray(s, dtype=float))


def tool_yaw(spec: TrajectorySpec) -> float:
    """The tool frame's heading about the vertical, rad: facing the path's centre from the base.

    A1 turns toward the centre anyway; turning the tool frame with it keeps A7 near zero wherever
    the path is, so the twist, not the path's placement, is what A7 has to do.
    """
    return float(np.arctan2(spec.center[1], spec.center[0]))


def tool_rotations(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """Desired flange orientations (m, 3, 3) at progress `s`: tool axis down, twisted about it."""
    yaw = tool_yaw(spec)
    heading = np.array(
        [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
    )
    angle = twist_angle(spec, s)
    cos, sin = np.cos(angle), np.sin(angle)
    # The twist turns about the tool's own z axis, so it multiplies on the right.
    turn = np.zeros((len(angle), 3, 3))
    turn[:, 0, 0], turn[:, 0, 1], turn[:, 1, 0], turn[:, 1, 1] = cos, -sin, sin, cos
    turn[:, 2, 2] = 1.0
    return heading @ TOOL_DOWN @ turn


def spiral(spec: TrajectorySpec, u: np.ndarray) -> np.ndarray:
    """The spiral kind's Path, a conical helix: the radius grows from 0 to `size` while it
    rises by `size`, in `turns` turns; placed by its seed (`placed`)."""
    angle = 2.0 * np.pi * spec.turns * u
    radius = spec.size * u
    helix = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), spec.size * (u - 0.5)])
    return placed(spec, helix)


def seed_turn(seed: int) -> float:
    """Where seed `seed` lies in [-0.5, 0.5): frac(seed/φ + 1/2) − 1/2, by Fibonacci hashing in
    exact integers, so any seed up to 2⁶³ counts. Consecutive seeds spread evenly over the
    interval (the three-gap theorem); seed 0 lies at 0."""
    return ((seed * _FIBONACCI + 2**63) % 2**64) / 2**64 - 0.5


def placed(spec: TrajectorySpec, offsets: np.ndarray) -> np.ndarray:
    """The spiral's and the pyramid's offsets (n, 3) as the spec's seed places them: turned
    about the vertical through the centre by `seed_turn` times the kind's SEED_TURNS, and
    mirrored (y → −y) for an odd seed. Another seed's path starts elsewhere and goes round the
    other way (a left-handed spiral, a pyramid drawn the other way) with the same shape, size
    and centre. Seed 0 is the path as it was before seeds placed it, bit for bit: old runs and
    their logs' digests keep their meaning."""
    if not spec.seed:
        return offsets
    angle = 2.0 * np.pi * seed_turn(spec.seed) * SEED_TURNS.get(spec.kind, 1.0)
    cos, sin = np.cos(angle), np.sin(angle)
    mirror = -1.0 if spec.seed % 2 else 1.0
    turn = np.array([[cos, -sin * mirror, 0.0], [sin, cos * mirror, 0.0], [0.0, 0.0, 1.0]])
    return offsets @ turn.T


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


def _by_arc_length(curve):
    """The same curve, parametrised by its arc-length fraction (so the timing law sets its speed).

    u(s) is a cubic spline through densely measured arc lengths: C², so the re-parametrised
    curve stays as smooth as the original and its joint accelerations stay continuous.
    """
    u = np.linspace(0.0, 1.0, _ARC_SAMPLES)
    length = _cumulative_length(curve(u))
    inverse = CubicSpline(length / length[-1], u)
    return lambda s: curve(np.clip(inverse(s), 0.0, 1.0))


def pyramid(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """The pyramid's offsets at its progress `s` (arc fraction): straight edges, the arm at rest
    at every corner (rest_points), so not a smooth Path."""
    vertices = _pyramid_vertices(spec)
    arc = _cumulative_length(vertices)
    target = s * arc[-1]
    return np.column_stack([np.interp(target, arc, vertices[:, i]) for i in range(3)])


def _pyramid_vertices(spec: TrajectorySpec) -> np.ndarray:
    """A square pyramid's edges (base half-width `size`, height `size`), in drawing order,
    placed by its seed (`placed`)."""
    h = spec.size / 2.0
    b0, b1, b2, b3 = ([sx * spec.size, sy * spec.size, -h] for sx, sy in _BASE_CORNERS)
    apex = [0.0, 0.0, h]
    return placed(spec, np.array([b0, apex, b1, b2, apex, b3, b0]))


def _cumulative_length(points: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


_BASE_CORNERS = ((1, 1), (-1, 1), (-1, -1), (1, -1))


# --- Joint-space excitation -----------------------------------------------------------------


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
