"""Gains far outside the search space: what `outside_search` says, and when it says nothing."""

import pytest

from gainfarm.schemas.gains import DEFAULT_GAINS, KD_RANGE, KP_RANGE, PDGains, outside_search


def with_gain(which: str, joint: int, value: float) -> PDGains:
    """The default gains with one gain (0-based joint) replaced."""
    gains = list(getattr(DEFAULT_GAINS, which))
    gains[joint] = value
    return DEFAULT_GAINS.model_copy(update={which: tuple(gains)})


def bounds(end: int) -> PDGains:
    """The search space's corner: every gain at its lowest (end 0) or highest (end 1)."""
    return PDGains(
        kp=tuple(k * KP_RANGE[end] for k in DEFAULT_GAINS.kp),
        kd=tuple(k * KD_RANGE[end] for k in DEFAULT_GAINS.kd),
    )


def test_gains_inside_the_search_space_or_on_its_bounds_say_nothing():
    assert outside_search(DEFAULT_GAINS) is None
    assert outside_search(bounds(0)) is None
    assert outside_search(bounds(1)) is None
    # A tenth of the lowest and ten times the highest: on the line, not beyond it.
    tenth = PDGains(kp=tuple(k / 10 for k in bounds(0).kp), kd=tuple(k / 10 for k in bounds(0).kd))
    assert outside_search(tenth) is None
    tenfold = PDGains(
        kp=tuple(k * 10 for k in bounds(1).kp), kd=tuple(k * 10 for k in bounds(1).kd)
    )
    assert outside_search(tenfold) is None


def test_exactly_ten_times_beyond_a_bound_says_nothing():
    # Typed as a user types them: 0.15 and 60000, not products that carry the bounds' rounding.
    assert outside_search(with_gain("kd", 2, 0.15)) is None  # A3's lowest Kd is 1.5
    assert outside_search(with_gain("kp", 0, 60000.0)) is None  # A1's highest Kp is 6000


@pytest.mark.parametrize(
    ("which", "joint", "value", "says"),
    [
        (
            "kp",
            0,
            63000.0,
            "kp of A1 is 63000 N·m/rad, 10.5× the search space's highest "
            "(6000 N·m/rad: 3× the default 2000)",
        ),
        (
            "kd",
            2,
            1.5 / 10.5,
            "kd of A3 is 0.142857 N·m·s/rad, 1/10.5 of the search space's lowest "
            "(1.5 N·m·s/rad: 0.1× the default 15)",
        ),
        (
            "kd",
            2,
            1e-6,
            "kd of A3 is 1e-06 N·m·s/rad, 1/1,500,000 of the search space's lowest "
            "(1.5 N·m·s/rad: 0.1× the default 15)",
        ),
        (  # a lost exponent: the factor as a power of ten, not thirty grouped figures
            "kp",
            0,
            1e30,
            "kp of A1 is 1e+30 N·m/rad, 1.7e+26× the search space's highest "
            "(6000 N·m/rad: 3× the default 2000)",
        ),
        (
            "kd",
            2,
            1e-12,
            "kd of A3 is 1e-12 N·m·s/rad, 1/1.5e+12 of the search space's lowest "
            "(1.5 N·m·s/rad: 0.1× the default 15)",
        ),
        (
            "kd",
            6,
            0.0,
            "kd of A7 is 0 N·m·s/rad, below the search space's lowest "
            "(0.1 N·m·s/rad: 0.1× the default 1)",
        ),
    ],
)
def test_a_gain_more_than_ten_times_beyond_a_bound_is_named_with_its_unit(
    which: str, joint: int, value: float, says: str
):
    assert outside_search(with_gain(which, joint, value)) == says


def test_of_several_gains_far_outside_the_furthest_is_named():
    gains = PDGains(
        kp=(1e5, *DEFAULT_GAINS.kp[1:]),  # 16.7× A1's highest
        kd=(*DEFAULT_GAINS.kd[:3], 1e-3, *DEFAULT_GAINS.kd[4:]),  # 1/1,500 of A4's lowest
    )
    found = outside_search(gains)
    assert found is not None and found.startswith("kd of A4 is 0.001 N·m·s/rad, 1/1,500 of")
