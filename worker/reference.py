"""System layer, part 3: the joint-space reference an episode tracks, computed once per spec.

Every reference is one the robot it is for can follow (a reference is of a trajectory on a robot,
`reference_for(spec, robot)`; the iiwa 14 by default): it stays inside the robot's joint ranges
and its data sheet's speed and acceleration limits (`Robot.limits`), checked here when it is
built.

- Cartesian kinds: the flange's path and orientation (worker/trajectories/) are solved by
  inverse kinematics (worker/ik.py) on a fine grid of the path's progress, and the joint path
  q(σ) of each rest-to-rest segment is a C² cubic spline through those solutions. Each segment
  is timed by the minimum-jerk law σ = φ(t/T_i), so joint speed scales as 1/T_i and acceleration
  as 1/T_i²: a segment's shortest feasible time is T_i* = T·max(speed ratio, √acceleration
  ratio), exactly. The requested duration is shared among the segments in proportion to T_i*
  (a kind's rests, such as the pyramid's corners, cut its path into segments), so the shortest
  feasible duration is Σ T_i*; a shorter request raises InfeasibleReference naming it.
- Joint-space kinds (fourier: a per-joint finite Fourier series scaled into the limits,
  always feasible): the kind's own motion, checked against the limits; a kind's shortest
  feasible duration is its own to say (`Kind.shortest_duration`).

The same trajectory is simulated thousands of times with different gains, so this runs once per
spec and the result is cached in the worker process.
"""

import itertools
import math
from dataclasses import dataclass
from functools import cache, lru_cache

import mujoco
import numpy as np
from scipy.interpolate import CubicSpline

from gainfarm.models import robot_of
from gainfarm.schemas.robot import DEFAULT_ROBOT, Robot
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.ik import (
    ORIENTATION_TOLERANCE,
    REACH_TOLERANCE,
    UnreachablePath,
    facing,
    kinematic_model,
    ready_posture,
    solve_path,
)
from gainfarm.worker.trajectories import (
    Kind,
    joint_motion,
    kind_of,
    minimum_jerk_derivatives,
    path_points,
    rest_points,
    sample_times,
    tool_rotations,
    tool_yaw,
)

PATH_SAMPLES = 1000  # IK solutions along a whole Cartesian path (shared by segment length)
MIN_SEGMENT_SAMPLES = 100  # and at least this many per rest-to-rest segment
# Samples of a segment's normalised time at which its speed and acceleration peaks are found:
# finer than the control ticks of any duration up to 20 s, so no tick sees a higher peak.
LIMIT_SAMPLES = 10001
LIMIT_TOLERANCE = 1e-9  # relative: a duration exactly at the limit is feasible
# Issue 49: a default reference uses at most this share of any joint's data-sheet speed and
# acceleration, on every arm (`default_duration`), leaving a controller room to catch up.
DEFAULT_SHARE = 0.9
DEFAULT_STEP = 0.5  # s: a longer default duration is a multiple of this


class InfeasibleReference(ValueError):
    """The path cannot be followed within the robot's speed and acceleration limits in time."""


@dataclass(frozen=True)
class Arm:
    """What a reference needs of its robot: its rigid chain (kinematics do not depend on the
    elastic joints' numbers nor on the inertials: the rigid chain serves every plant), its
    flange, its joints' names and limits as arrays. A joint's range is its hinge's in the built
    model (the robot puts its data sheet's there; a range need not be symmetric: the Panda's)."""

    robot: Robot
    model: mujoco.MjModel
    low: np.ndarray  # rad, each joint's lowest angle
    high: np.ndarray  # rad, each joint's highest angle
    speed: np.ndarray  # rad/s
    acceleration: np.ndarray  # rad/s²

    @property
    def joints(self) -> int:
        return len(self.robot.joint_names)

    @property
    def flange(self) -> str:
        return self.robot.flange

    def joint(self, index: int) -> str:
        return self.robot.joint_names[index]


@cache
def arm_of(robot: str = DEFAULT_ROBOT) -> Arm:
    """The robot named so, as references need it (once per process)."""
    found = robot_of(robot)
    model = kinematic_model(robot)
    limits = found.limits
    speed, acceleration = (
        np.array(values, dtype=float) for values in (limits.speed, limits.acceleration)
    )
    ranges = model.jnt_range.copy()
    return Arm(found, model, ranges[:, 0], ranges[:, 1], speed, acceleration)


@dataclass(frozen=True)
class Reference:
    """Desired motion, one row per control tick. Arrays are read-only: the cache shares them."""

    t: np.ndarray  # (n,) s
    ee: np.ndarray  # (n, 3) desired flange position, m
    q: np.ndarray  # (n, joints) rad
    qd: np.ndarray  # (n, joints) rad/s
    qdd: np.ndarray  # (n, joints) rad/s²


@lru_cache(maxsize=64)
def reference_for(spec: TrajectorySpec, robot: str = DEFAULT_ROBOT) -> Reference:
    """The joint-space reference for `spec` on `robot` (a plant's `robot`).

    Raises UnreachablePath if the arm cannot reach the path, InfeasibleReference if it cannot
    follow it within its speed and acceleration limits in `spec.duration`.
    """
    arm = arm_of(robot)
    t = sample_times(spec)
    kind = kind_of(spec)
    if kind.joint_motion is not None:
        q, qd, qdd = _joint_motion(spec, kind, t, arm)
        ee, _ = _flange(arm, q)
    else:
        q, qd, qdd, s = _cartesian(spec, t, arm)
        ee = path_points(spec, s)
        reached, rotations = _flange(arm, q)
        _check_pose(spec, s, ee, reached, rotations)
    if np.any((q < arm.low) | (q > arm.high)):  # the IK keeps clear of the ranges; the guarantee
        raise UnreachablePath(f"the {spec.kind} leaves the joint ranges")
    reference = Reference(t, ee, q, qd, qdd)
    for array in (t, ee, q, qd, qdd):
        array.flags.writeable = False
    return reference


def forget_robots() -> None:
    """Forget every robot's references and kinematics this process cached: for a robot
    registered under a name another held before (gainfarm.testing.robots registers one for its
    checks), whose references are its own."""
    for cached in (arm_of, reference_for, _segments, facing):
        cached.cache_clear()


# --- Cartesian kinds ------------------------------------------------------------------------


@dataclass(frozen=True)
class _Segment:
    """One rest-to-rest piece of a joint path: q(σ) for σ in [0, 1], and its peaks at T = 1 s."""

    path: CubicSpline  # σ → q
    start: float  # the path's progress at σ = 0
    end: float  # and at σ = 1
    peak_speed: np.ndarray  # (joints,) max |dq/dt| over the segment if it took 1 s, rad/s
    peak_acceleration: np.ndarray  # (joints,) max |d²q/dt²| likewise, rad/s²
    shortest: float  # its shortest feasible time, s: speed scales as 1/T, acceleration as 1/T²


def shortest_duration(spec: TrajectorySpec, robot: str = DEFAULT_ROBOT) -> float:
    """The shortest duration, rounded up to 0.1 s, at which `spec`'s motion is feasible.

    Cartesian kinds: Σ T_i* of its segments (which needs the inverse kinematics, cached); a
    joint-space kind says its own (the fourier kind scales itself into the limits at any
    duration).
    """
    kind = kind_of(spec)
    if kind.joint_motion is not None:
        return round_up(_declared_shortest(spec, kind))
    return round_up(sum(segment.shortest for segment in _segments(_path_of(spec), robot)))


def default_duration(spec: TrajectorySpec, robot: str = DEFAULT_ROBOT) -> float:
    """The duration `spec`'s motion runs by default on `robot` (its own duration ignored):
    TrajectorySpec's default (5 s), or, on an arm that needs longer to follow it within
    DEFAULT_SHARE of its speed and acceleration limits, the shortest multiple of DEFAULT_STEP
    that does (the Kinova Gen3's slow wrist: its default spiral and pyramid take 5.5 s). A
    Cartesian reference's peak share is its shortest feasible duration over its duration (each
    segment is timed by its own shortest time: speed the ratio, acceleration its square), so
    that duration keeps every joint within the share; the fourier kind scales itself to 0.85 at
    any duration."""
    standard = float(TrajectorySpec.model_fields["duration"].default)
    need = shortest_duration(spec, robot) / DEFAULT_SHARE
    if need <= standard:
        return standard
    return math.ceil(need / DEFAULT_STEP - 1e-9) * DEFAULT_STEP


def path_progress(spec: TrajectorySpec, robot: str = DEFAULT_ROBOT) -> np.ndarray:
    """The path's progress s (arc-length fraction) at every control tick of a Cartesian spec.

    reference_for(spec).ee is path_points(spec, s); the tool's twist there is twist_angle(spec, s).
    Raises as reference_for does.
    """
    return _cartesian(spec, sample_times(spec), arm_of(robot))[3]


def _cartesian(
    spec: TrajectorySpec, t: np.ndarray, arm: Arm
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """q, qd, qdd at the ticks `t`, and the path's progress there."""
    segments = _segments(_path_of(spec), arm.robot.name)
    shortest = np.array([segment.shortest for segment in segments])
    _check_feasible(spec, segments, shortest, arm)
    durations = spec.duration * shortest / shortest.sum()
    starts = np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    which = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(segments) - 1)
    q, qd, qdd = (np.empty((len(t), arm.joints)) for _ in range(3))
    progress = np.empty(len(t))
    for i, segment in enumerate(segments):
        rows = which == i
        tau = np.clip((t[rows] - starts[i]) / durations[i], 0.0, 1.0)
        sigma, rate, acceleration = minimum_jerk_derivatives(tau)
        dq = segment.path(sigma, 1)
        q[rows] = segment.path(sigma)
        qd[rows] = dq * (rate / durations[i])[:, None]
        qdd[rows] = (
            segment.path(sigma, 2) * (rate**2)[:, None] + dq * acceleration[:, None]
        ) / durations[i] ** 2
        progress[rows] = segment.start + sigma * (segment.end - segment.start)
    return q, qd, qdd, progress


def _path_of(spec: TrajectorySpec) -> TrajectorySpec:
    """The spec with its duration fixed: the joint path depends on the geometry alone, so the
    inverse kinematics is shared by every duration of one path (and the limit checks)."""
    return spec.model_copy(update={"duration": 1.0})


@lru_cache(maxsize=16)
def _segments(spec: TrajectorySpec, robot: str) -> tuple[_Segment, ...]:
    """The joint path of each rest-to-rest segment, from one IK pass along the whole path."""
    arm = arm_of(robot)
    rests = rest_points(spec)
    grids = [
        np.linspace(0.0, 1.0, max(MIN_SEGMENT_SAMPLES, round(PATH_SAMPLES * (end - start))) + 1)
        for start, end in itertools.pairwise(rests)
    ]
    # Consecutive segments share their rest point: it is solved once.
    progress = _progress(grids, rests)
    q = solve_path(
        arm.model,
        arm.flange,
        path_points(spec, progress),
        tool_rotations(spec, progress),
        posture=ready_posture(tool_yaw(spec), robot),
        progress=progress,
    )
    tau = np.linspace(0.0, 1.0, LIMIT_SAMPLES)
    sigma, rate, acceleration = minimum_jerk_derivatives(tau)
    segments = []
    first = 0
    for grid, (start, end) in zip(grids, itertools.pairwise(rests), strict=True):
        path = CubicSpline(grid, q[first : first + len(grid)], axis=0)
        first += len(grid) - 1
        dq = path(sigma, 1)
        speed = np.abs(dq * rate[:, None]).max(axis=0)
        accel = np.abs(path(sigma, 2) * (rate**2)[:, None] + dq * acceleration[:, None])
        accel = accel.max(axis=0)
        shortest = max(
            float(np.max(speed / arm.speed)), math.sqrt(float(np.max(accel / arm.acceleration)))
        )
        segments.append(_Segment(path, float(start), float(end), speed, accel, shortest))
    return tuple(segments)


def _progress(grids: list[np.ndarray], rests: np.ndarray) -> np.ndarray:
    parts = [rests[0] + grids[0] * (rests[1] - rests[0])]
    for grid, (start, end) in zip(grids[1:], itertools.pairwise(rests[1:]), strict=True):
        parts.append(start + grid[1:] * (end - start))
    return np.concatenate(parts)


def _check_feasible(
    spec: TrajectorySpec, segments: tuple[_Segment, ...], shortest: np.ndarray, arm: Arm
) -> None:
    """Raise InfeasibleReference, naming the binding joint and the shortest duration, if needed."""
    total = float(shortest.sum())
    if total <= spec.duration * (1.0 + LIMIT_TOLERANCE):
        return
    durations = spec.duration * shortest / total
    speed = np.max([s.peak_speed / d for s, d in zip(segments, durations, strict=True)], axis=0)
    accel = np.max(
        [s.peak_acceleration / d**2 for s, d in zip(segments, durations, strict=True)], axis=0
    )
    speed_ratio, accel_ratio = speed / arm.speed, accel / arm.acceleration
    binding = np.maximum(speed_ratio, np.sqrt(accel_ratio))
    joint = int(np.argmax(binding))
    if speed_ratio[joint] >= math.sqrt(accel_ratio[joint]):
        need = f"{speed_ratio[joint]:.2f}x its speed limit"
    else:
        need = f"{accel_ratio[joint]:.2f}x its acceleration limit"
    raise InfeasibleReference(
        f"the {spec.duration:g} s {spec.kind} is too fast for {arm.robot.name}: "
        f"{arm.joint(joint)} would need {need}; "
        f"the shortest feasible duration is {round_up(total):.1f} s"
    )


def round_up(duration: float) -> float:
    """The shortest multiple of 0.1 s that the feasibility check accepts for `duration`.

    A hair of rounding error does not add a step (3.9000000001 s is 3.9 s, as the check's
    tolerance accepts it), and the result is always accepted.
    """
    tenths = math.ceil(duration * 10.0 - 1e-9)
    while tenths / 10.0 * (1.0 + LIMIT_TOLERANCE) < duration:
        tenths += 1
    return tenths / 10.0


def _check_pose(
    spec: TrajectorySpec,
    progress: np.ndarray,
    desired: np.ndarray,
    reached: np.ndarray,
    rotations: np.ndarray,
) -> None:
    """The guarantee at every tick, between the IK's grid points too: a jump in the IK's
    solutions (a branch switch) would show here as a pose missed in between."""
    miss = np.linalg.norm(reached - desired, axis=1)
    # The angle between two frames from their Frobenius distance, accurate for small angles.
    diff = np.linalg.norm(rotations - tool_rotations(spec, progress), axis=(1, 2))
    turn = 2.0 * np.arcsin(np.minimum(diff / (2.0 * math.sqrt(2.0)), 1.0))
    worst = int(np.argmax(np.maximum(miss / REACH_TOLERANCE, turn / ORIENTATION_TOLERANCE)))
    if miss[worst] > REACH_TOLERANCE or turn[worst] > ORIENTATION_TOLERANCE:
        raise UnreachablePath(
            f"the {spec.kind} cannot be followed smoothly: at {100 * progress[worst]:.0f} % "
            f"of the path the flange would miss its pose by {miss[worst] * 1000:.2f} mm "
            f"and {math.degrees(turn[worst]):.2f}°"
        )


# --- Joint-space kinds ------------------------------------------------------------------------


def _joint_motion(
    spec: TrajectorySpec, kind: Kind, t: np.ndarray, arm: Arm
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kind's q, qd, qdd at the ticks `t` on the arm, checked: a plug-in's is a stranger's
    code, and the motion must be one the arm can follow (InfeasibleReference naming the kind's
    shortest duration if it is too fast)."""
    motion = tuple(np.asarray(part, dtype=float) for part in joint_motion(kind, spec, t, arm.robot))
    if len(motion) != 3 or any(
        part.shape != (len(t), arm.joints) or not np.all(np.isfinite(part)) for part in motion
    ):
        raise ValueError(
            f"trajectory kind {spec.kind!r}: its joint motion is not q, qd, qdd of "
            f"({len(t)}, {arm.joints}) finite values for {arm.robot.name}'s joints"
        )
    q, qd, qdd = motion
    speed = np.abs(qd).max(axis=0) / arm.speed
    acceleration = np.abs(qdd).max(axis=0) / arm.acceleration
    binding = np.maximum(speed, acceleration)
    joint = int(np.argmax(binding))
    if binding[joint] > 1.0 + LIMIT_TOLERANCE:
        which = "speed" if speed[joint] >= acceleration[joint] else "acceleration"
        raise InfeasibleReference(
            f"the {spec.duration:g} s {spec.kind} is too fast for {arm.robot.name}: "
            f"{arm.joint(joint)} would need {binding[joint]:.2f}x its {which} limit; "
            f"the shortest feasible duration is {round_up(_declared_shortest(spec, kind)):.1f} s"
        )
    return q, qd, qdd


def _declared_shortest(spec: TrajectorySpec, kind: Kind) -> float:
    """A joint-space kind's shortest feasible duration, as it declares it."""
    if kind.shortest_duration is None:
        raise ValueError(
            f"trajectory kind {spec.kind!r}: a joint motion without its shortest duration"
        )
    return float(kind.shortest_duration(spec))


# --- Both -----------------------------------------------------------------------------------


def flange_positions(q: np.ndarray, robot: str = DEFAULT_ROBOT) -> np.ndarray:
    """(n, 3) flange positions, m, of the arm at joint angles `q` (n, joints): kinematics alone."""
    return _flange(arm_of(robot), np.asarray(q, dtype=float))[0]


def _flange(arm: Arm, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flange positions (n, 3) and orientations (n, 3, 3) at q: kinematics alone (the gravity
    feed-forward depends on the plant's inertials: worker.episode.gravity_for computes it)."""
    model = arm.model
    data = mujoco.MjData(model)
    site = model.site(arm.flange).id
    positions = np.empty((len(q), 3))
    rotations = np.empty((len(q), 3, 3))
    for k, qk in enumerate(q):
        data.qpos[:] = qk
        mujoco.mj_kinematics(model, data)
        positions[k] = data.site_xpos[site]
        rotations[k] = data.site_xmat[site].reshape(3, 3)
    return positions, rotations
