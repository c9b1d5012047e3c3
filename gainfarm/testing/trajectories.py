"""The conformance kit for a trajectory kind of the gainfarm.trajectories group: the checks
gainfarm's own kinds pass, for a plug-in's author to run on theirs (docs/plugins.md, "Checking
your plug-in").

Each check is given a sensible spec of the kind (one the arm can follow: a duration at least
its shortest) and the robot it runs on (a gainfarm.robots name: the iiwa 14 by default; place a
Cartesian spec in that robot's workspace), as a worker would be. Call them, or subclass
`TrajectoryChecks` in a test module as pytest collects it:

    from gainfarm.testing.trajectories import TrajectoryChecks

    class TestCircle(TrajectoryChecks):
        spec = TrajectorySpec(kind="circle", duration=1.0, size=0.02)

    class TestCircleOnTheUR5e(TrajectoryChecks):
        robot = "ur5e"
        spec = TrajectorySpec(kind="circle", duration=1.0, size=0.02, center=(0.45, 0.13, 0.35))

The references are the worker's own (worker.reference), the inverse kinematics included: a few
seconds a spec.
"""

import re
from typing import ClassVar

import numpy as np
import pytest

from gainfarm.models import plant_preset, robot_of
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.robot import DEFAULT_ROBOT
from gainfarm.schemas.trajectory import MIN_DURATION, TrajectorySpec
from gainfarm.schemas.wire import JobStatus
from gainfarm.worker.job import simulate
from gainfarm.worker.reference import (
    InfeasibleReference,
    arm_of,
    reference_for,
    shortest_duration,
)
from gainfarm.worker.trajectories import kind_of, path_points, rest_points, sample_times

_PROGRESS = np.linspace(0.0, 1.0, 501)  # where a Cartesian kind's path is looked at
AT_REST = 1e-6  # rad/s and rad/s²: what "at rest" at an end allows (rounding only)
LIMIT_TOLERANCE = 1e-6  # relative, over the robot's limits


def check_the_same_spec_gives_the_same_motion(
    spec: TrajectorySpec, robot: str = DEFAULT_ROBOT
) -> None:
    """The kind's motion depends on its spec (and robot) only: computed twice afresh (no cache),
    the references are equal to the bit, and so are its path and rests."""
    uncached = reference_for.__wrapped__  # type: ignore[attr-defined]
    first, again = uncached(spec, robot), uncached(spec, robot)
    for name in ("t", "ee", "q", "qd", "qdd"):
        assert np.array_equal(getattr(first, name), getattr(again, name)), (
            f"{spec.kind}: its reference's {name} differs between two computations"
        )
    if kind_of(spec).path is not None:
        assert np.array_equal(path_points(spec, _PROGRESS), path_points(spec, _PROGRESS))
        assert np.array_equal(rest_points(spec), rest_points(spec))


def check_the_path_has_the_shape_it_promises(
    spec: TrajectorySpec, robot: str = DEFAULT_ROBOT
) -> None:
    """A Cartesian kind: the flange's positions, one finite 3-vector per progress value, within
    the cube of half-width `size` about the centre, turned any way (a seed may turn it: √3·size
    from the centre at most); its rests increase from 0 to 1. Any kind: the reference
    is one finite row per control tick, one column per joint of the robot."""
    ticks = len(sample_times(spec))
    reference = reference_for(spec, robot)
    joints = arm_of(robot).joints
    for name, columns in (("ee", 3), ("q", joints), ("qd", joints), ("qdd", joints)):
        values = getattr(reference, name)
        assert values.shape == (ticks, columns), f"{spec.kind}: {name} is {values.shape}"
        assert np.all(np.isfinite(values)), f"{spec.kind}: {name} is not finite"
    if kind_of(spec).path is None:
        return
    points = path_points(spec, _PROGRESS)
    assert points.shape == (len(_PROGRESS), 3) and np.all(np.isfinite(points))
    reach = np.linalg.norm(points - np.asarray(spec.center), axis=1).max()
    assert reach <= np.sqrt(3.0) * spec.size * (1.0 + 1e-9), (
        f"{spec.kind}: the path goes {reach:.4f} m from its centre, beyond the cube of "
        f"half-width {spec.size} m about it"
    )
    rests = rest_points(spec)
    assert rests[0] == 0.0 and rests[-1] == pytest.approx(1.0) and np.all(np.diff(rests) > 0)


def check_the_arm_rests_at_both_ends(spec: TrajectorySpec, robot: str = DEFAULT_ROBOT) -> None:
    """At the first and the last tick every joint is at rest: no speed, no acceleration."""
    reference = reference_for(spec, robot)
    for tick in (0, -1):
        moving = max(np.abs(reference.qd[tick]).max(), np.abs(reference.qdd[tick]).max())
        assert moving <= AT_REST, f"{spec.kind}: not at rest at tick {tick} ({moving:.3g})"


def check_a_sensible_spec_is_feasible(spec: TrajectorySpec, robot: str = DEFAULT_ROBOT) -> None:
    """The spec's motion stays within the robot's joint ranges, speed and acceleration limits,
    its duration is at least the kind's shortest, and a worker runs an episode of it on the
    robot's realistic plant with its default gains."""
    reference = reference_for(spec, robot)
    arm = arm_of(robot)
    slack = LIMIT_TOLERANCE * (arm.high - arm.low)
    assert np.all(reference.q >= arm.low - slack) and np.all(reference.q <= arm.high + slack), (
        f"{spec.kind}: beyond a joint's range"
    )
    for values, limits, what in (
        (reference.qd, arm.speed, "speed limit"),
        (reference.qdd, arm.acceleration, "acceleration limit"),
    ):
        over = np.abs(values).max(axis=0) / limits
        assert np.all(over <= 1.0 + LIMIT_TOLERANCE), f"{spec.kind}: beyond a joint's {what}"
    assert shortest_duration(spec, robot) <= spec.duration
    episode = EpisodeSpec(
        gains=robot_of(robot).default_gains,
        trajectory=spec,
        plant=plant_preset("realistic", robot),
    )
    outcome = simulate(episode)
    assert outcome.status == JobStatus.ok, f"{spec.kind}: the episode {outcome.status}"


def check_a_spec_too_fast_is_refused_naming_the_shortest_duration(
    spec: TrajectorySpec, robot: str = DEFAULT_ROBOT
) -> None:
    """Below its shortest duration the kind's spec is refused (InfeasibleReference) in one line
    that names that duration; at it, the spec is feasible. (A kind feasible at any duration,
    as the fourier kind is, has nothing to refuse.)"""
    shortest = shortest_duration(spec, robot)
    assert shortest >= MIN_DURATION and np.isfinite(shortest)
    reference_for(spec.model_copy(update={"duration": shortest}), robot)  # raises if infeasible
    if shortest <= MIN_DURATION:
        return
    too_fast = spec.model_copy(update={"duration": max(MIN_DURATION, round(shortest / 2, 1))})
    with pytest.raises(InfeasibleReference) as refused:
        reference_for(too_fast, robot)
    message = str(refused.value)
    assert "\n" not in message, f"{spec.kind}: a refusal of several lines"
    assert re.search(rf"shortest feasible duration is {shortest:.1f} s", message), message


class TrajectoryChecks:
    """The checks as pytest tests: subclass it as Test..., giving a sensible spec of the kind
    (`spec`) and the robot it runs on (`robot`, the iiwa 14 unless given), or override the
    `spec` fixture (parametrised, to check several)."""

    spec: ClassVar[TrajectorySpec]
    robot: ClassVar[str] = DEFAULT_ROBOT

    @pytest.fixture(name="spec")
    def _spec(self) -> TrajectorySpec:
        return self.spec

    def test_the_same_spec_gives_the_same_motion(self, spec: TrajectorySpec) -> None:
        check_the_same_spec_gives_the_same_motion(spec, self.robot)

    def test_the_path_has_the_shape_it_promises(self, spec: TrajectorySpec) -> None:
        check_the_path_has_the_shape_it_promises(spec, self.robot)

    def test_the_arm_rests_at_both_ends(self, spec: TrajectorySpec) -> None:
        check_the_arm_rests_at_both_ends(spec, self.robot)

    def test_a_sensible_spec_is_feasible(self, spec: TrajectorySpec) -> None:
        check_a_sensible_spec_is_feasible(spec, self.robot)

    def test_a_spec_too_fast_is_refused_naming_the_shortest_duration(
        self, spec: TrajectorySpec
    ) -> None:
        check_a_spec_too_fast_is_refused_naming_the_shortest_duration(spec, self.robot)
