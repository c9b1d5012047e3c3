"""System layer, part 1: what the arm is asked to do, before any kinematics: the trajectory
kinds, one module each (spiral, random, pyramid, fourier), through one protocol, `Kind`.

Pure NumPy/SciPy here (the fourier kind's module uses MuJoCo's kinematics). A Cartesian kind
is a geometric path: the flange's position p(s) and orientation R(s) as functions of the path's
progress s in [0, 1] (its arc-length fraction), with the points where the arm comes to rest
(`rest_points`). worker/reference.py turns it into a joint path by inverse kinematics and times
each rest-to-rest piece with the minimum-jerk law within the robot's limits. A joint-space kind
(the fourier kind) gives the joint motion directly in time.

Every kind, built-in or not, is a name of the gainfarm.trajectories plug-in group, found by
`kind_of` (gainfarm.plugins.load): a `Kind`, or the simple form a third party may give, a
`Path` function (Kind(path=it)). A worker without the kind refuses the job (worker/job.py).
Nothing here or in worker/reference.py branches on a kind's name: what a kind does is what its
hooks say.
"""

import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.interpolate import CubicSpline

from gainfarm import plugins
from gainfarm.schemas.robot import Robot
from gainfarm.schemas.trajectory import CONTROL_PERIOD_NS, TrajectorySpec

# The flange frame pointing straight down (columns: its x, y, z axes in the base frame): the
# ready posture's frame (worker/ik.py) once its 2.4° tilt is removed, so A7 starts near zero.
TOOL_DOWN = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
_ARC_SAMPLES = 4097  # dense samples of a curve to measure its arc length and its curvature
_FIBONACCI = 11400714819323198485  # ⌊2⁶⁴/φ⌋, odd: Knuth's multiplicative hashing constant


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


# --- the protocol ------------------------------------------------------------------------------


class Path(Protocol):
    """The simple form of a Cartesian kind, a plug-in's function (the spiral's and the random
    kind's curves are two): the flange's offsets from the spec's centre, (len(u), 3) in m, at the
    curve's parameter `u` (an array of values in [0, 1]). The curve is smooth (twice continuously
    differentiable: the arm's accelerations follow its curvature) and the arm rests at both of
    its ends; any parametrisation will do, the worker takes it by arc length and times it with
    the minimum-jerk law. The tool points down with the spec's twist about it. It may read the
    spec's size, seed, turns and waypoints; a path the arm cannot reach, or follow within its
    limits in the spec's duration, is refused (worker/reference.py) as the built-in kinds' are.
    """

    def __call__(self, spec: TrajectorySpec, u: np.ndarray) -> np.ndarray: ...


# A joint-space motion: q, qd, qdd (len(t), joints) in rad, rad/s, rad/s² at the times t (s),
# of the robot given (its home, limits and kinematics: the fourier kind's); a kind written
# before robots were many takes (spec, t) alone, and is then the iiwa 14's.
Motion = tuple[np.ndarray, np.ndarray, np.ndarray]
JointMotion = (
    Callable[[TrajectorySpec, np.ndarray, Robot], Motion]
    | Callable[[TrajectorySpec, np.ndarray], Motion]
)


@dataclass(frozen=True)
class Kind:
    """A trajectory kind, as the worker takes it: either a Cartesian `path` or a joint-space
    `joint_motion`, each with its optional hooks. A plug-in's entry point may name one of these,
    or a bare `Path` function (Kind(path=it)).

    - `path(spec, u)`: a Cartesian path as `Path` says: the flange's offsets from the centre.
    - `by_arc_length`: the path's parameter already is its arc-length fraction (the pyramid's
      straight edges), so the worker takes it as it is instead of re-parametrising it.
    - `rests(spec)`: the progress values, increasing from 0 to 1, at which the arm comes to rest
      (the pyramid's corners); between two of them it moves along one rest-to-rest minimum-jerk
      segment. Without it: the two ends.
    - `joint_motion(spec, t, robot)`: a joint-space motion (the fourier kind): q, qd, qdd at the
      tick times `t` for `robot` (a schemas.robot.Robot: one column per joint), starting and
      ending at rest; the worker checks it against the robot's ranges and limits and computes
      the flange's path from it. (A `joint_motion(spec, t)` of two parameters is taken too: it
      knows one arm, and a worker refuses its motion on an arm of another joint count.)
    - `shortest_duration(spec)`: a joint-space kind's shortest feasible duration, s, which the
      worker names when it refuses a spec as too fast (a Cartesian kind's it measures itself).
    """

    path: Path | None = None
    by_arc_length: bool = False
    rests: Callable[[TrajectorySpec], np.ndarray] | None = None
    joint_motion: JointMotion | None = None
    shortest_duration: Callable[[TrajectorySpec], float] | None = None


def kind_of(spec: TrajectorySpec) -> Kind:
    """The spec's kind (a name of the gainfarm.trajectories group), as a `Kind`. PluginError if
    this process does not have it, or it is neither a Kind nor a Path function."""
    found = plugins.load(plugins.TRAJECTORIES, spec.kind)
    if isinstance(found, Kind):
        kind = found
    elif callable(found):
        kind = Kind(path=found)
    else:
        kind = None
    if kind is None or (kind.path is None) == (kind.joint_motion is None):
        raise plugins.PluginError(
            f"{plugins.TRAJECTORIES}: {spec.kind!r} is a {type(found).__name__}, not a path "
            "function nor a Kind with either a path or a joint motion"
        )
    return kind


def joint_motion(kind: Kind, spec: TrajectorySpec, t: np.ndarray, robot: Robot) -> Motion:
    """The kind's joint motion at the times `t` on `robot`, called as its hook takes it."""
    if kind.joint_motion is None:
        raise ValueError(f"trajectory kind {spec.kind!r} has no joint motion")
    if _takes_robot(kind.joint_motion):
        return kind.joint_motion(spec, t, robot)  # type: ignore[call-arg]
    return kind.joint_motion(spec, t)  # type: ignore[call-arg]


def _takes_robot(hook: Callable[..., Motion]) -> bool:
    """Whether a joint-motion hook takes the robot: a third positional parameter, or *args."""
    try:
        parameters = inspect.signature(hook).parameters.values()
    except (TypeError, ValueError):  # no signature to read (a builtin): the newer form
        return True
    positional = [p for p in parameters if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return len(positional) >= 3 or any(p.kind == p.VAR_POSITIONAL for p in parameters)


def label(spec: TrajectorySpec) -> str:
    """A trajectory's short name in reports: its kind and seed ("random 3"); a Cartesian path
    moved off the default centre says where it is instead of seed 0 ("spiral at (0.5, 0.1,
    0.4) m"). PluginError as `kind_of`."""
    default = TrajectorySpec.model_fields["center"].default
    if kind_of(spec).path is None or tuple(spec.center) == tuple(default):
        return f"{spec.kind} {spec.seed}"
    at = "at ({:g}, {:g}, {:g}) m".format(*spec.center)
    return f"{spec.kind} {spec.seed} {at}" if spec.seed else f"{spec.kind} {at}"


# --- Cartesian paths ------------------------------------------------------------------------


def path_points(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """Flange positions (m, 3) in the base frame at the path's progress `s` (arc fraction).
    PluginError if the spec's kind is a plug-in this process does not have."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    kind = kind_of(spec)
    if kind.path is None:
        raise ValueError(f"the {spec.kind} kind is defined in joint space, not as a path")
    curve = _checked(spec, kind.path)
    offsets = curve(s) if kind.by_arc_length else _by_arc_length(curve)(s)
    return np.asarray(spec.center) + offsets


def _checked(spec: TrajectorySpec, path: Path) -> Callable[[np.ndarray], np.ndarray]:
    """The kind's path for this spec, u → offsets, checked: a plug-in's is a stranger's code."""

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
    """Progress values where the arm is at rest: the ends, and those the kind adds (the
    pyramid's corners). Between two of them the arm moves along one rest-to-rest minimum-jerk
    segment. ValueError if the kind's are not increasing from 0 to 1."""
    kind = kind_of(spec)
    if kind.rests is None:
        return np.array([0.0, 1.0])
    rests = np.asarray(kind.rests(spec), dtype=float)
    if (
        rests.ndim != 1
        or len(rests) < 2
        or not np.all(np.isfinite(rests))
        or rests[0] != 0.0
        or not np.isclose(rests[-1], 1.0)
        or np.any(np.diff(rests) <= 0.0)
    ):
        raise ValueError(f"trajectory kind {spec.kind!r}: its rests are not increasing from 0 to 1")
    return rests


def twist_angle(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """The tool's turn about its own axis (flange z, right-handed), rad, at progress `s`.

    twist·sin(2πs): zero at both ends, where the arm is at rest, and one full swing each way in
    between, so A7 turns by about 2·twist over every path.
    """
    return spec.twist * np.sin(2.0 * np.pi * np.asarray(s, dtype=float))


def tool_yaw(spec: TrajectorySpec) -> float:
    """The tool frame's heading about the vertical, rad: facing the path's centre from the base.

    The arm's first joint turns toward the centre anyway (worker.ik.ready_posture); turning the
    tool frame with it keeps the last joint near its home angle wherever the path is, so the
    twist, not the path's placement, is what the last joint has to do.
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


def seed_turn(seed: int) -> float:
    """Where seed `seed` lies in [-0.5, 0.5): frac(seed/φ + 1/2) − 1/2, by Fibonacci hashing in
    exact integers, so any seed up to 2⁶³ counts. Consecutive seeds spread evenly over the
    interval (the three-gap theorem); seed 0 lies at 0."""
    return ((seed * _FIBONACCI + 2**63) % 2**64) / 2**64 - 0.5


def placed(spec: TrajectorySpec, offsets: np.ndarray, turns: float = 1.0) -> np.ndarray:
    """A path's offsets (n, 3) as the spec's seed places them (the spiral's and the pyramid's):
    turned about the vertical through the centre by `seed_turn` times `turns` (the kind's
    choice: how far a seed may turn it), and mirrored (y → −y) for an odd seed. Another seed's
    path starts elsewhere and goes round the other way (a left-handed spiral, a pyramid drawn
    the other way) with the same shape, size and centre. Seed 0 is the path as it was before
    seeds placed it, bit for bit: old runs and their logs' digests keep their meaning."""
    if not spec.seed:
        return offsets
    angle = 2.0 * np.pi * seed_turn(spec.seed) * turns
    cos, sin = np.cos(angle), np.sin(angle)
    mirror = -1.0 if spec.seed % 2 else 1.0
    turn = np.array([[cos, -sin * mirror, 0.0], [sin, cos * mirror, 0.0], [0.0, 0.0, 1.0]])
    return offsets @ turn.T


def _by_arc_length(
    curve: Callable[[np.ndarray], np.ndarray],
) -> Callable[[np.ndarray], np.ndarray]:
    """The same curve, parametrised by its arc-length fraction (so the timing law sets its speed).

    u(s) is a cubic spline through densely measured arc lengths: C², so the re-parametrised
    curve stays as smooth as the original and its joint accelerations stay continuous.
    """
    u = np.linspace(0.0, 1.0, _ARC_SAMPLES)
    length = cumulative_length(curve(u))
    inverse = CubicSpline(length / length[-1], u)
    return lambda s: curve(np.clip(inverse(s), 0.0, 1.0))


def cumulative_length(points: np.ndarray) -> np.ndarray:
    """The length along a polyline (n, 3) up to each of its points, from 0."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
