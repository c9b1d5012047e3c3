"""The statistics behind the experiments' findings: the numbers scipy gives, and plain words
that refuse to decide what the data cannot."""

import csv
import io
import math

import pytest
from scipy import stats as scipy_stats

from gainfarm.analytic.experiments import statistics as st

HIGH = [10.0, 11.0, 12.0, 13.0, 14.0, 15.0, 16.0, 17.0]
LOW = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.5]


def parse(data: bytes) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(data.decode())))


def test_a_clear_difference_is_significant_with_a12_on_the_larger_side() -> None:
    result = st.compare(HIGH, LOW)
    expected = scipy_stats.mannwhitneyu(HIGH, LOW, alternative="two-sided")
    assert result.p_value == pytest.approx(expected.pvalue) and result.p_value < 0.05
    assert result.a12 == 1.0 and st.compare(LOW, HIGH).a12 == 0.0
    assert (result.median_a, result.median_b) == (13.5, 3.5)
    assert result.ci_low <= 10.0 <= result.ci_high and result.ci_low > 0
    assert (result.n_a, result.n_b) == (8, 8)
    assert st.decide(result, "high", "low").startswith("high is better than low")
    assert st.decide(result, "high", "low", higher_is_better=False).startswith(
        "low is better than high"
    )
    assert st.better(result) == "a" and st.better(result, higher_is_better=False) == "b"


def test_paired_samples_take_the_wilcoxon_signed_rank_test() -> None:
    a, b = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [2.0, 3.5, 4.0, 5.5, 6.0, 7.5]
    result = st.compare(a, b, paired=True)
    assert result.p_value == pytest.approx(scipy_stats.wilcoxon(a, b).pvalue)
    assert result.test == "Wilcoxon signed-rank" and result.min_p == pytest.approx(2 / 2**6)
    with pytest.raises(ValueError, match="equal lengths"):
        st.compare([1.0, 2.0], [1.0], paired=True)


def test_identical_samples_cannot_decide() -> None:
    result = st.compare([0.5] * 8, [0.5] * 8)
    assert result.p_value == 1.0 and result.a12 == 0.5
    assert st.decide(result).startswith("cannot decide") and st.better(result) is None


def test_three_against_three_can_never_decide_and_says_why() -> None:
    result = st.compare([10.0, 11.0, 12.0], [1.0, 2.0, 3.0])
    assert result.min_p == pytest.approx(0.1) == result.p_value  # as far apart as can be
    assert not st.decidable(result) and st.better(result) is None
    words = st.decide(result, "big", "small")
    assert words.startswith("cannot decide") and "0.1" in words and "3 against 3" in words


def test_stats_csv_has_exactly_the_agreed_columns_and_scipys_numbers() -> None:
    rows = [
        st.StatsRow("popsize", "high vs low", "hypervolume", st.compare(HIGH, LOW)),
        st.StatsRow("popsize", "same", "error_m", st.compare([1.0, 2.0], [1.0, 2.0])),
    ]
    written = parse(st.stats_csv(rows))
    assert list(written[0]) == [
        "experiment",
        "comparison",
        "metric",
        "median_a",
        "median_b",
        "p_value",
        "a12",
        "ci_low",
        "ci_high",
        "n_a",
        "n_b",
    ]
    first = written[0]
    assert first["comparison"] == "high vs low" and first["metric"] == "hypervolume"
    expected = scipy_stats.mannwhitneyu(HIGH, LOW, alternative="two-sided").pvalue
    assert float(first["p_value"]) == pytest.approx(expected)
    assert float(first["a12"]) == 1.0 and (first["n_a"], first["n_b"]) == ("8", "8")
    assert float(written[1]["p_value"]) == 1.0 and float(written[1]["a12"]) == 0.5


def test_a_single_value_a_side_gives_no_interval() -> None:
    result = st.compare([1.0], [2.0, 3.0])
    assert math.isnan(result.ci_low) and math.isnan(result.ci_high)
    assert st.decide(result).startswith("cannot decide")


def test_holm_steps_down_and_keeps_the_order() -> None:
    # Sorted 0.01, 0.03, 0.04 times 3, 2, 1: 0.03, 0.06, then max(0.06, 0.04).
    assert st.holm([0.04, 0.01, 0.03]) == pytest.approx([0.06, 0.03, 0.06])
    assert st.holm([0.5, math.nan, 0.9]) == pytest.approx([1.0, math.nan, 1.0], nan_ok=True)


def test_stats_csv_adds_the_holm_column_only_where_an_experiment_adjusts() -> None:
    result = st.compare(HIGH, LOW)
    adjusted = st.stats_csv(
        [
            st.StatsRow("algorithms", "a vs ref", "hypervolume", result, 2 * result.p_value),
            st.StatsRow("algorithms", "rule", "hypervolume", result),  # in no family
        ]
    )
    first, second = parse(adjusted)
    assert list(first) == [*st.STATS_COLUMNS, "p_holm"]
    assert float(first["p_holm"]) == 2 * float(first["p_value"]) and second["p_holm"] == ""
    plain = parse(st.stats_csv([st.StatsRow("popsize", "a vs b", "hypervolume", result)]))
    assert list(plain[0]) == list(st.STATS_COLUMNS)


def test_holm_adjusted_judges_each_claim_as_one_of_its_family() -> None:
    def shifted(by: float) -> st.Comparison:
        return st.compare(HIGH, [v - by for v in HIGH])

    alone = {"near": shifted(3), "far": shifted(5)}  # p = 0.045 and 0.0045, each alone
    family = st.holm_adjusted(alone)
    assert list(family) == ["near", "far"]
    assert family["far"].p_value == pytest.approx(2 * alone["far"].p_value)  # the least, doubled
    assert family["near"].p_value == pytest.approx(alone["near"].p_value)  # the last, as it was
    assert family["near"].a12 == alone["near"].a12 and family["near"].ci_low == alone["near"].ci_low
    # Two claims each significant alone (p = 0.045) are not as a family of two (0.09).
    twice = st.holm_adjusted({"a": shifted(3), "b": shifted(3)})
    assert all(st.significant(shifted(3)) and not st.significant(r) for r in twice.values())
    assert [r.p_value for r in twice.values()] == pytest.approx([2 * shifted(3).p_value] * 2)
    # Four against four reaches 0.029 alone; as one of two claims, Holm's least is 0.057.
    small = st.holm_adjusted({k: st.compare(HIGH[:4], LOW[:4]) for k in "ab"})
    assert all(not st.decidable(r) and r.min_p == pytest.approx(4 / 70) for r in small.values())
    assert st.holm_adjusted({}) == {}


@pytest.mark.parametrize(("claims", "reps"), [(1, 6), (2, 7), (6, 8), (12, 9)])
def test_least_reps_lets_every_claim_of_the_family_reach_significance(
    claims: int, reps: int
) -> None:
    # Wilcoxon on n pairs cannot go below 2 / 2^n; Holm multiplies the smallest p by the family.
    assert st.least_reps(claims, (True, False)) == reps
    assert claims * 2 / 2**reps < 0.05 <= claims * 2 / 2 ** (reps - 1)
