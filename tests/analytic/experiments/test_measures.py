"""The practical measures beside the hypervolume: the error at one torque smoothness, the
recommended controller, and medians with their intervals."""

import math
from pathlib import Path

import pytest

from gainfarm.analytic.experiments import statistics as st
from gainfarm.analytic.experiments.measures import (
    difference,
    error_at,
    median,
    median_interval,
    recommended,
    shown,
    smoothness_level,
)
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import (
    BASELINE_JSON,
    Baseline,
    FrontMember,
    RunRecord,
    baseline_json,
)
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.objectives import NO_EPISODE

# A front from stiff to soft: f_t falls by a decade per member while the error doubles.
FRONT = [(0.001, 10.0), (0.002, 1.0), (0.004, 0.1)]
CHATTERING = (0.0005, 1e4)  # the most accurate member, 10³ times rougher than the next


def test_the_level_is_the_least_f_t_every_front_reaches() -> None:
    other = [(0.0015, 5.0), (0.003, 0.5)]
    assert smoothness_level([FRONT, other]) == 0.5
    # Penalties (no episode, a diverged one) never set it; a front of penalties only is left out.
    diverged = (0.01, 0.001)
    assert (
        smoothness_level([[*FRONT, NO_EPISODE, diverged], other, [NO_EPISODE]], {diverged}) == 0.5
    )
    assert math.isnan(smoothness_level([[NO_EPISODE], []]))


def test_the_error_at_a_level_reads_the_front_there_not_its_most_accurate_member() -> None:
    assert error_at(FRONT, 1.0) == 0.002  # a member just at the level
    assert error_at(FRONT, 10**0.5) == pytest.approx(0.0015)  # halfway in log f_t: interpolated
    assert error_at(FRONT, 10.0) == error_at(FRONT, 1e6) == 0.001  # the most accurate, no further
    assert math.isnan(error_at(FRONT, 0.09))  # no member that smooth
    # A chattering member, a dominated one and penalties change nothing at the level...
    noisy = [*FRONT, CHATTERING, (0.003, 2.0), NO_EPISODE]
    assert error_at(noisy, 1.0) == 0.002 and error_at(noisy, 10**0.5) == pytest.approx(0.0015)
    diverged = (0.0001, 0.01)  # a diverged episode's point, however good it looks
    assert error_at([*noisy, diverged], 1.0, {diverged}) == 0.002
    assert error_at([*noisy, diverged], 1.0) == 0.0001  # (were it measured, it would be best)
    # ...where the most accurate member's error is the chattering one's.
    assert min(p[0] for p in noisy if p != NO_EPISODE) < 0.001
    assert math.isnan(error_at([NO_EPISODE], 1.0)) and math.isnan(error_at([], 1.0))


def member(f_acc: float, f_t: float, scale: float) -> FrontMember:
    return FrontMember(
        kp=[k * scale for k in DEFAULT_GAINS.kp], kd=DEFAULT_GAINS.kd, objectives=(f_acc, f_t)
    )


def test_the_recommended_controller_is_the_runs_pick_not_its_most_accurate(tmp_path: Path) -> None:
    front = [member(*CHATTERING, 8.0), *(member(*p, 2.0 / 2**i) for i, p in enumerate(FRONT))]
    record = RunRecord(tmp_path, RunConfig(), front=front)
    # Without baseline.json (a run stopped before it scored the defaults): the knee.
    assert recommended(record).name == "knee"
    # The defaults at 3 mm and f_t 2: two members dominate them, the knee of those is chosen.
    baseline = Baseline(gains=DEFAULT_GAINS, objectives=(0.003, 2.0), diverged=False)
    (tmp_path / BASELINE_JSON).write_bytes(baseline_json(baseline))
    chosen = recommended(record)
    assert chosen.name == "recommended" and chosen.member.objectives == (0.002, 1.0)
    # Defaults no member dominates: the closest to dominating them.
    better = Baseline(gains=DEFAULT_GAINS, objectives=(0.0019, 0.9), diverged=False)
    (tmp_path / BASELINE_JSON).write_bytes(baseline_json(better))
    assert recommended(record).name == "closest"
    assert recommended(RunRecord(tmp_path, RunConfig())) is None


def test_a_median_comes_with_its_bootstrap_interval() -> None:
    values = [5.0, 1.0, 4.0, 2.0, 3.0, math.nan]
    middle, low, high = median_interval(values)
    assert middle == 3.0 == median(values) and 1.0 <= low < 3.0 < high <= 5.0
    assert median_interval(values) == (middle, low, high)  # seeded
    assert median_interval([2.0, 2.0]) == (2.0, 2.0, 2.0)
    one = median_interval([7.0])
    assert one[0] == 7.0 and math.isnan(one[1]) and math.isnan(one[2])
    assert all(math.isnan(v) for v in median_interval([math.nan])) and math.isnan(median([]))
    assert shown([0.00561]) == "5.61" and shown([]) == "n/a"
    assert shown([0.001, 0.002, 0.003]).startswith("2.00 [")


def test_a_difference_is_shown_in_its_unit_significant_or_not() -> None:
    result = st.compare([1.0, 1.1, 1.2], [1.5, 1.6, 1.7])
    assert not st.decidable(result)  # 3 against 3: no test can decide...
    said = difference(result, "mm")
    assert said.startswith("-0.5 mm [") and said.endswith("]")  # ...its size is still shown
    assert difference(st.compare([1.0], [2.0])) == "-1"  # no interval from one value a side
