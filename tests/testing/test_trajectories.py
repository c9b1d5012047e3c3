"""Every built-in trajectory kind passes the conformance kit a plug-in's author runs
(gainfarm.testing.trajectories): the project's own kinds are checked as a third party's are.
Seeds other than 0 too, as the spiral and the pyramid are turned by theirs. And a third party's
joint-space kind, the form of the fourier kind, passes it too."""

import math
from collections.abc import Iterator

import numpy as np
import pytest

from gainfarm import plugins
from gainfarm.models import robot_of
from gainfarm.schemas.robot import ACCELERATION_LIMITS, SPEED_LIMITS
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.testing.trajectories import (
    TrajectoryChecks,
    check_a_spec_too_fast_is_refused_naming_the_shortest_duration,
    check_the_arm_rests_at_both_ends,
)
from gainfarm.worker.ik import READY_POSTURE
from gainfarm.worker.reference import InfeasibleReference, shortest_duration
from gainfarm.worker.trajectories import (
    Kind,
    cumulative_length,
    minimum_jerk_derivatives,
    rest_points,
)

SENSIBLE = [
    TrajectorySpec(kind=kind, duration=3.0, seed=seed)
    for kind in plugins.builtin_names(plugins.TRAJECTORIES)
    for seed in (0, 3)
]


class TestEveryBuiltInKind(TrajectoryChecks):
    @pytest.fixture(name="spec", params=SENSIBLE, ids=lambda spec: f"{spec.kind}-{spec.seed}")
    def _spec(self, request: pytest.FixtureRequest) -> TrajectorySpec:
        return request.param


# The UR5e (6 joints): every kind in its workspace, about its own centre.
UR5E_CENTER = robot_of("ur5e").workspace.center
ON_THE_UR5E = [
    TrajectorySpec(kind=kind, duration=4.0, seed=seed, center=UR5E_CENTER)
    for kind in plugins.builtin_names(plugins.TRAJECTORIES)
    for seed in (0, 3)
]


class TestEveryBuiltInKindOnTheUR5e(TrajectoryChecks):
    robot = "ur5e"

    @pytest.fixture(name="spec", params=ON_THE_UR5E, ids=lambda spec: f"{spec.kind}-{spec.seed}")
    def _spec(self, request: pytest.FixtureRequest) -> TrajectorySpec:
        return request.param


# A third party's joint-space kind, in one process: A1 swings by SWING rad and back to rest on a
# minimum-jerk law, whose speed and acceleration peaks are 1.875 and 10/√3 times SWING/T and
# SWING/T²: its shortest feasible duration follows.
SWING = 1.0  # rad


def swing(spec: TrajectorySpec, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    phi, rate, acceleration = minimum_jerk_derivatives(np.clip(t / spec.duration, 0.0, 1.0))
    q = np.tile(READY_POSTURE, (len(t), 1))
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    q[:, 0] += SWING * phi
    qd[:, 0] = SWING * rate / spec.duration
    qdd[:, 0] = SWING * acceleration / spec.duration**2
    return q, qd, qdd


def swing_shortest(spec: TrajectorySpec) -> float:
    return max(
        1.875 * SWING / SPEED_LIMITS[0],
        math.sqrt(10 / math.sqrt(3) * SWING / ACCELERATION_LIMITS[0]),
    )


class TestAJointSpaceKindOfAThirdParty(TrajectoryChecks):
    spec = TrajectorySpec(kind="swing", duration=3.0)

    @pytest.fixture(autouse=True)
    def _registered(self) -> Iterator[None]:
        kind = Kind(joint_motion=swing, shortest_duration=swing_shortest)
        plugins.register(plugins.TRAJECTORIES, "swing", kind)
        yield
        plugins.unregister(plugins.TRAJECTORIES, "swing")


def test_the_kit_fails_a_kind_that_lies_about_its_shortest_duration_or_does_not_rest() -> None:
    """The checks can fail: a kind claiming any duration will do, and one that stops moving
    only after its last tick, are each caught by the check they break."""

    def restless(spec: TrajectorySpec, t: np.ndarray) -> tuple[np.ndarray, ...]:
        q, qd, qdd = swing(spec, t * 0.9)  # still moving at the end
        return q, qd * 0.9, qdd * 0.81

    kinds = {
        "boaster": Kind(joint_motion=swing, shortest_duration=lambda spec: 0.1),
        "restless": Kind(joint_motion=restless, shortest_duration=swing_shortest),
    }
    checks = {
        "boaster": check_a_spec_too_fast_is_refused_naming_the_shortest_duration,
        "restless": check_the_arm_rests_at_both_ends,
    }
    for name, kind in kinds.items():
        plugins.register(plugins.TRAJECTORIES, name, kind)
        try:
            with pytest.raises((AssertionError, InfeasibleReference)):
                checks[name](TrajectorySpec(kind=name, duration=3.0))
        finally:
            plugins.unregister(plugins.TRAJECTORIES, name)


# docs/plugins.md's square, verbatim: a third party's Cartesian kind that rests at its corners.
CORNERS = np.array([[1, 1, 0], [-1, 1, 0], [-1, -1, 0], [1, -1, 0], [1, 1, 0]], dtype=float)


def edges(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    points = spec.size * CORNERS
    arc = cumulative_length(points)
    return np.column_stack([np.interp(s * arc[-1], arc, points[:, i]) for i in range(3)])


def corners(spec: TrajectorySpec) -> np.ndarray:
    arc = cumulative_length(CORNERS)
    return arc / arc[-1]


class TestTheDocsSquareOfAThirdParty(TrajectoryChecks):
    spec = TrajectorySpec(kind="square", duration=3.0)

    @pytest.fixture(autouse=True)
    def _registered(self) -> Iterator[None]:
        kind = Kind(path=edges, by_arc_length=True, rests=corners)
        plugins.register(plugins.TRAJECTORIES, "square", kind)
        yield
        plugins.unregister(plugins.TRAJECTORIES, "square")

    def test_it_rests_at_its_corners(self, spec: TrajectorySpec) -> None:
        np.testing.assert_allclose(rest_points(spec), [0.0, 0.25, 0.5, 0.75, 1.0])
        assert shortest_duration(spec) == 2.8  # as docs/plugins.md says
