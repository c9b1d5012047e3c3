import numpy as np
import pytest

from schemas import CONTROL_PERIOD, TrajectoryKind, TrajectorySpec
from worker.trajectories import cartesian_path, minimum_jerk

KINDS = list(TrajectoryKind)


@pytest.mark.parametrize("kind", KINDS)
def test_paths_start_and_end_at_rest(kind):
    path = cartesian_path(TrajectorySpec(kind=kind, duration=3.0))
    speed = np.linalg.norm(np.diff(path, axis=0), axis=1) / CONTROL_PERIOD
    assert path.shape == (1501, 3)
    assert speed[0] < 1e-3 and speed[-1] < 1e-3
    assert speed.max() > 0.05  # and they do move


@pytest.mark.parametrize("kind", KINDS)
def test_paths_stay_within_their_size_around_the_centre(kind):
    spec = TrajectorySpec(kind=kind, center=(0.5, 0.1, 0.45), size=0.1)
    offset = cartesian_path(spec) - np.array(spec.center)
    assert np.abs(offset).max() <= spec.size + 1e-9


def test_random_path_depends_on_its_seed_only():
    first = cartesian_path(TrajectorySpec(kind="random", seed=1))
    assert np.array_equal(first, cartesian_path(TrajectorySpec(kind="random", seed=1)))
    assert not np.allclose(first, cartesian_path(TrajectorySpec(kind="random", seed=2)))


def test_pyramid_turns_sharp_corners_and_spiral_does_not():
    def sharpest_turn(kind: str) -> float:
        velocity = np.diff(cartesian_path(TrajectorySpec(kind=kind)), axis=0)
        moving = velocity[np.linalg.norm(velocity, axis=1) > 1e-5]
        unit = moving / np.linalg.norm(moving, axis=1, keepdims=True)
        cosines = np.clip(np.sum(unit[1:] * unit[:-1], axis=1), -1, 1)
        return float(np.degrees(np.arccos(cosines)).max())

    assert sharpest_turn("pyramid") > 60
    assert sharpest_turn("spiral") < 10


def test_minimum_jerk_is_monotone_from_zero_to_one():
    s = minimum_jerk(np.linspace(0, 1, 101))
    assert s[0] == 0 and s[-1] == pytest.approx(1)
    assert np.all(np.diff(s) >= 0)
