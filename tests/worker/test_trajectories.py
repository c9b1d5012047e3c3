import numpy as np
import pytest

from gainfarm.schemas import TrajectoryKind, TrajectorySpec
from gainfarm.worker.trajectories import (
    TOOL_DOWN,
    Kind,
    kind_of,
    minimum_jerk,
    minimum_jerk_derivatives,
    path_points,
    rest_points,
    seed_turn,
    tool_rotations,
    twist_angle,
)
from gainfarm.worker.trajectories.fourier import fourier_coefficients, fourier_series
from gainfarm.worker.trajectories.pyramid import pyramid
from gainfarm.worker.trajectories.random import RANDOM_MIN_TURN_RADIUS
from gainfarm.worker.trajectories.spiral import spiral

CARTESIAN_KINDS = (TrajectoryKind.spiral, TrajectoryKind.random, TrajectoryKind.pyramid)

S = np.linspace(0.0, 1.0, 4001)


def test_the_kinds_are_the_three_paths_and_the_fourier_excitation():
    assert set(TrajectoryKind) == {*CARTESIAN_KINDS, TrajectoryKind.fourier}
    for kind in CARTESIAN_KINDS:
        assert kind_of(TrajectorySpec(kind=kind)).path is not None
    assert kind_of(TrajectorySpec(kind="fourier")).joint_motion is not None
    with pytest.raises(ValueError, match="joint space"):
        path_points(TrajectorySpec(kind="fourier"), S)


@pytest.mark.parametrize(
    ("made", "why"),
    [
        (Kind(), "neither"),
        (Kind(path=lambda spec, u: u, joint_motion=lambda spec, t: (t, t, t)), "either"),
        (3, "int"),
    ],
)
def test_a_kind_of_no_form_the_worker_takes_is_refused_naming_it(made: object, why: str):
    from gainfarm import plugins

    plugins.register(plugins.TRAJECTORIES, "shapeless", made)
    try:
        with pytest.raises(plugins.PluginError, match="'shapeless'") as raised:
            kind_of(TrajectorySpec(kind="shapeless"))
        assert "\n" not in str(raised.value)
    finally:
        plugins.unregister(plugins.TRAJECTORIES, "shapeless")


@pytest.mark.parametrize("kind", CARTESIAN_KINDS)
def test_paths_stay_within_their_size_around_the_centre(kind):
    spec = TrajectorySpec(kind=kind, center=(0.5, 0.1, 0.45), size=0.1)
    offset = path_points(spec, S) - np.array(spec.center)
    assert np.abs(offset).max() <= spec.size + 1e-9
    assert np.abs(offset).max() > 0.5 * spec.size  # and they fill it


@pytest.mark.parametrize("kind", CARTESIAN_KINDS)
def test_paths_are_parametrised_by_their_arc_length(kind):
    points = path_points(TrajectorySpec(kind=kind), S)
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    # Even steps in s are even steps along the path (the pyramid's corners split a step).
    assert np.percentile(step, 99) / np.median(step) < 1.01
    assert step.max() <= 1.01 * np.median(step)


def test_default_paths_are_of_a_size_a_reviewer_recognises():
    for kind in CARTESIAN_KINDS:
        spec = TrajectorySpec(kind=kind)
        points = path_points(spec, S)
        extent = points.max(axis=0) - points.min(axis=0)
        assert 0.08 <= extent[:2].max() <= 0.25, kind


def test_random_path_depends_on_its_seed_only():
    first = path_points(TrajectorySpec(kind="random", seed=1), S)
    assert np.array_equal(first, path_points(TrajectorySpec(kind="random", seed=1), S))
    assert not np.allclose(first, path_points(TrajectorySpec(kind="random", seed=2), S))


# --- the seed of the spiral and the pyramid: where they start and which way they go ----------


def unseeded_spiral(spec: TrajectorySpec, u: np.ndarray) -> np.ndarray:
    """The spiral's Path as it was before its seed placed it (47f30f3), verbatim."""
    angle = 2.0 * np.pi * spec.turns * u
    radius = spec.size * u
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), spec.size * (u - 0.5)])


def unseeded_pyramid(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """The pyramid's offsets as they were before its seed placed it (47f30f3), verbatim."""
    h = spec.size / 2.0
    b0, b1, b2, b3 = ([sx * spec.size, sy * spec.size, -h] for sx, sy in CORNERS)
    vertices = np.array([b0, [0.0, 0.0, h], b1, b2, [0.0, 0.0, h], b3, b0])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(vertices, axis=0), axis=1))])
    return np.column_stack([np.interp(s * arc[-1], arc, vertices[:, i]) for i in range(3)])


CORNERS = ((1, 1), (-1, 1), (-1, -1), (1, -1))


def swept(offsets: np.ndarray) -> float:
    """The area the path sweeps about the vertical through the centre, seen from above,
    counter-clockwise positive (the shoelace formula): its sign is the way it goes round."""
    x, y = offsets[:, 0], offsets[:, 1]
    return float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]) / 2)


PLACED_KINDS = ("spiral", "pyramid")


@pytest.mark.parametrize(
    "fields", [{}, {"center": (0.5, -0.1, 0.45), "size": 0.12, "turns": 3.5}, {"size": 0.01}]
)
def test_seed_0_is_the_spiral_and_the_pyramid_of_before_bit_for_bit(fields):
    spiral_spec = TrajectorySpec(kind="spiral", seed=0, **fields)
    assert np.array_equal(spiral(spiral_spec, S), unseeded_spiral(spiral_spec, S))
    pyramid_spec = TrajectorySpec(kind="pyramid", seed=0, **fields)
    assert np.array_equal(pyramid(pyramid_spec, S), unseeded_pyramid(pyramid_spec, S))


@pytest.mark.parametrize("kind", PLACED_KINDS)
def test_another_seed_is_the_same_shape_turned_about_the_centre_and_mirrored_if_odd(kind):
    center = np.array([0.5, 0.1, 0.4])
    unturned = path_points(TrajectorySpec(kind=kind, center=center), S) - center
    rests = rest_points(TrajectorySpec(kind=kind))
    turns = []
    for seed in (1, 2, 3, 4, 2**63 - 1):
        spec = TrajectorySpec(kind=kind, center=center, seed=seed)
        offsets = path_points(spec, S) - center
        assert np.array_equal(offsets, path_points(spec, S) - center)  # the seed's path only
        assert not np.allclose(offsets, unturned, atol=1e-3), seed  # another path...
        # ...of the same shape: the same height and distance from the vertical through the
        # centre at every point, the same corners, the same length.
        np.testing.assert_allclose(offsets[:, 2], unturned[:, 2], atol=1e-12)
        radius = np.linalg.norm(offsets[:, :2], axis=1)
        np.testing.assert_allclose(radius, np.linalg.norm(unturned[:, :2], axis=1), atol=1e-9)
        np.testing.assert_allclose(rest_points(spec), rests, atol=1e-12)
        # Turned by the angle between their first points off the axis (the spiral's end, the
        # pyramid's first corner), and mirrored for an odd seed: it goes round the other way.
        angle = np.arctan2(offsets[-1, 1], offsets[-1, 0]) - np.arctan2(
            unturned[-1, 1], unturned[-1, 0]
        )
        turns.append(np.angle(np.exp(1j * angle)))
        assert swept(offsets) == pytest.approx((-1 if seed % 2 else 1) * swept(unturned))
    assert len({round(t, 6) for t in turns}) == len(turns)  # each seed turns it otherwise


def test_the_seeds_turns_spread_evenly_and_seed_0_does_not_turn():
    assert seed_turn(0) == 0.0
    shares = np.array([seed_turn(seed) for seed in range(100)])
    assert np.all((shares >= -0.5) & (shares < 0.5))
    # The three-gap theorem: consecutive seeds' shares cut the circle into gaps of at most three
    # lengths, for 1/φ none more than φ² ≈ 2.62 times another (no clusters, no holes).
    gaps = np.diff(np.sort(np.append(shares, shares.min() + 1.0)))
    assert len(np.unique(gaps.round(12))) <= 3
    assert gaps.max() < 2.7 * gaps.min() and gaps.max() < 2.0 / len(shares)
    assert -0.5 <= seed_turn(2**63 - 1) < 0.5 and seed_turn(2**63 - 1) != seed_turn(1)


@pytest.mark.parametrize("seed", range(10))
def test_random_paths_turn_no_tighter_than_their_minimum_radius(seed):
    spec = TrajectorySpec(kind="random", seed=seed)
    s = np.linspace(0.0, 1.0, 20001)
    points = path_points(spec, s)
    d1 = np.gradient(points, s, axis=0)
    d2 = np.gradient(d1, s, axis=0)
    speed = np.linalg.norm(d1, axis=1)
    radius = speed**3 / np.linalg.norm(np.cross(d1, d2), axis=1)
    assert radius[5:-5].min() >= 0.95 * RANDOM_MIN_TURN_RADIUS * spec.size


def test_pyramid_rests_only_at_its_corners():
    spec = TrajectorySpec(kind="pyramid")
    rests = rest_points(spec)
    corners = path_points(spec, rests) - np.array(spec.center)
    h, a = spec.size / 2, spec.size
    apex = [0.0, 0.0, h]
    expected = [[a, a, -h], apex, [-a, a, -h], [-a, -a, -h], apex, [a, -a, -h], [a, a, -h]]
    np.testing.assert_allclose(corners, expected, atol=1e-12)
    assert rests[0] == 0.0 and rests[-1] == pytest.approx(1.0)
    for kind in ("spiral", "random"):
        np.testing.assert_array_equal(rest_points(TrajectorySpec(kind=kind)), [0.0, 1.0])


def test_pyramid_turns_sharp_corners_and_spiral_does_not():
    def sharpest_turn(kind: str) -> float:
        velocity = np.diff(path_points(TrajectorySpec(kind=kind), S), axis=0)
        unit = velocity / np.linalg.norm(velocity, axis=1, keepdims=True)
        cosines = np.clip(np.sum(unit[1:] * unit[:-1], axis=1), -1, 1)
        return float(np.degrees(np.arccos(cosines)).max())

    assert sharpest_turn("pyramid") > 60
    assert sharpest_turn("spiral") < 10


@pytest.mark.parametrize("twist", [0.0, 0.4, 1.5])
def test_the_tool_points_down_and_twists_about_its_axis(twist):
    spec = TrajectorySpec(center=(0.4, 0.4, 0.3), twist=twist)
    rotations = tool_rotations(spec, S)
    np.testing.assert_allclose(rotations[:, :, 2], np.tile([0.0, 0.0, -1.0], (len(S), 1)))
    np.testing.assert_allclose(
        rotations @ rotations.transpose(0, 2, 1), np.tile(np.eye(3), (len(S), 1, 1)), atol=1e-12
    )
    # The heading of the tool's x axis: the centre's bearing (45°), turned by the twist about
    # the tool axis, which points down (so a positive twist turns it clockwise, seen from above).
    x = rotations[:, :, 0]
    heading = np.arctan2(-x[:, 1], -x[:, 0])  # TOOL_DOWN's x axis points to -x
    angle = np.angle(np.exp(1j * (heading - np.pi / 4 + twist_angle(spec, S))))
    np.testing.assert_allclose(angle, 0.0, atol=1e-12)
    assert twist_angle(spec, np.array([0.0, 1.0])) == pytest.approx([0.0, 0.0], abs=1e-12)
    assert np.ptp(twist_angle(spec, S)) == pytest.approx(2 * twist)
    np.testing.assert_array_equal(TOOL_DOWN[:, 2], [0.0, 0.0, -1.0])


def test_minimum_jerk_is_monotone_from_zero_to_one_with_its_derivatives():
    tau = np.linspace(0, 1, 10001)
    s = minimum_jerk(tau)
    assert s[0] == 0 and s[-1] == pytest.approx(1)
    assert np.all(np.diff(s) >= 0)
    phi, rate, acceleration = minimum_jerk_derivatives(tau)
    np.testing.assert_array_equal(phi, s)
    np.testing.assert_allclose(rate[1:-1], np.gradient(phi, tau)[1:-1], atol=1e-6)
    np.testing.assert_allclose(acceleration[1:-1], np.gradient(rate, tau)[1:-1], atol=1e-3)
    assert rate[[0, -1]] == pytest.approx([0, 0]) and acceleration[[0, -1]] == pytest.approx([0, 0])
    assert rate.max() == pytest.approx(1.875)


@pytest.mark.parametrize("harmonics", [2, 5, 10])
def test_fourier_series_start_and_end_at_rest_and_are_periodic(harmonics):
    spec = TrajectorySpec(kind="fourier", harmonics=harmonics, seed=3)
    a, b = fourier_coefficients(spec, 7)
    assert a.shape == b.shape == (7, harmonics)
    k = np.arange(1, harmonics + 1)
    np.testing.assert_allclose(a @ k, 0.0, atol=1e-12)
    np.testing.assert_allclose(b @ k**2, 0.0, atol=1e-12)
    x, dx, ddx = fourier_series(a, b, np.array([0.0, 1.0]))
    np.testing.assert_allclose(x, 0.0, atol=1e-12)
    np.testing.assert_allclose(dx, 0.0, atol=1e-11)
    np.testing.assert_allclose(ddx, 0.0, atol=1e-10)
    tau = np.linspace(0, 1, 20001)
    x, dx, ddx = fourier_series(a, b, tau)
    np.testing.assert_allclose(dx, np.gradient(x, tau, axis=0), atol=1e-4 * np.abs(dx).max())
    np.testing.assert_allclose(ddx, np.gradient(dx, tau, axis=0), atol=1e-3 * np.abs(ddx).max())
    assert np.all(np.ptp(x, axis=0) > 0)  # every joint moves


def test_fourier_coefficients_depend_on_the_seed_only():
    first = fourier_coefficients(TrajectorySpec(kind="fourier", seed=4), 7)
    again = fourier_coefficients(TrajectorySpec(kind="fourier", seed=4, size=0.2), 7)
    other = fourier_coefficients(TrajectorySpec(kind="fourier", seed=5), 7)
    assert all(np.array_equal(x, y) for x, y in zip(first, again, strict=True))
    assert not np.allclose(first[0], other[0])


@pytest.mark.parametrize(
    "field",
    [{"twist": -0.1}, {"twist": 2.0}, {"harmonics": 1}, {"harmonics": 11}, {"twist": float("nan")}],
)
def test_new_fields_are_bounded(field):
    with pytest.raises(ValueError):
        TrajectorySpec(**field)
