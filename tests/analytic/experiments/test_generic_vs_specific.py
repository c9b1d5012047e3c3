"""The generic-against-specific experiment at toy size, both designs: on a real local farm, and in
this process."""

import json
import re
from pathlib import Path

import pytest

from gainfarm.analytic.experiments import generic_vs_specific, measures
from gainfarm.analytic.experiments.runner import ALL_KINDS, Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.picks import picks
from gainfarm.analytic.tuning.records import BASELINE_JSON, read_baseline, read_run
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import balancing_weights, score
from gainfarm.schemas.trajectory import TrajectoryKind
from tests.analytic.experiments.common import (
    BASE,
    PNG,
    in_process,
    on_farm,
    refusal,
    rows,
    stats_rows,
)

EFFECTS = {"error_at_level_mm", "recommended_error_mm", "recommended_f_t"}
CLAIMS = {"hypervolume", "dominated_share"}


def default_point(out: Path, kind: str) -> tuple[float, float]:
    """The default gains' (f_acc, f_t) on `kind`, from their episode's log."""
    [log] = (out / "cross" / f"default-gains-on-{kind}" / "episodes").glob("*.mcap")
    found = score(read_episode(log))
    return found.f_acc, found.f_t


def config(out: Path, run: str) -> RunConfig:
    return RunConfig.model_validate_json((out / "runs" / run / "config.json").read_text())


@pytest.mark.slow
def test_on_a_real_farm(tmp_path: Path, endpoints: list[str]) -> None:
    generic_vs_specific.run(
        Experiment(tmp_path, on_farm(endpoints)), BASE, reps=1, kinds=[TrajectoryKind.pyramid]
    )
    results = rows(tmp_path / "results.csv")
    assert [(r["design"], r["controller"]) for r in results] == [
        ("paper", "generic"),
        ("paper", "specific"),
        ("held-out", "generic"),
        ("held-out", "specific"),
    ]
    assert {r["test_trajectory"] for r in results} == {"pyramid"}
    # The paper's generic controller saw the pyramid; the held-out one never did. Each is
    # balanced by the default gains' own episodes on its set, read back from their logs.
    paper, held_out = (
        config(tmp_path, "generic-all-rep0"),
        config(tmp_path, "generic-no-pyramid-rep0"),
    )
    assert [t.kind for t in paper.trajectories] == list(ALL_KINDS)
    assert [t.kind for t in held_out.trajectories] == ["spiral", "random"]
    defaults = {kind.value: default_point(tmp_path, kind.value) for kind in ALL_KINDS}
    assert paper.objective_weights == balancing_weights(list(defaults.values()))
    assert held_out.objective_weights == balancing_weights([defaults["spiral"], defaults["random"]])
    for generic in ("generic-all-rep0", "generic-no-pyramid-rep0"):
        cross = tmp_path / "cross" / f"{generic}-on-pyramid" / "episodes"
        assert len(list(cross.glob("*.mcap"))) >= 1
    # The effects in physical units, from the specific run's own front: its recommended member
    # (as `analytic export` picks it), and its error at the smoothness every front reaches.
    specific = next(r for r in results if r["controller"] == "specific")
    record = read_run(tmp_path / "runs" / "specific-pyramid-rep0")
    pick = picks(record.front, read_baseline(record.directory / BASELINE_JSON))[0]
    assert specific["recommended"] == pick.name
    assert (float(specific["recommended_f_acc"]), float(specific["recommended_f_t"])) == (
        pick.member.objectives
    )
    level = float(specific["f_t_level"])
    assert {float(r["f_t_level"]) for r in results} == {level}  # one level per test trajectory
    own = [m.objectives for m in record.front]
    assert float(specific["error_at_level"]) == pytest.approx(measures.error_at(own, level))
    assert level >= min(m.f_t for m in record.front)  # a smoothness every front reaches
    assert (tmp_path / "generic-vs-specific.png").read_bytes().startswith(PNG)
    report = (tmp_path / "report.md").read_text()
    for question in generic_vs_specific.QUESTIONS.values():
        assert f"## {question}" in report
    assert "on the pyramid (in the generic set): hypervolume (f_t on a log scale" in report
    assert "on the pyramid (held out of the generic set): hypervolume (f_t on a log scale" in report
    assert report.count("By dominance, paired by repetition: cannot decide") == 2  # 1 pair
    # Each effect as medians and their difference (no interval from one repetition).
    for effect in ("error at one torque smoothness", "the recommended controllers' error"):
        assert (
            len(re.findall(rf"{effect} [\d.]+ against [\d.]+ mm \([+-][\d.e+-]+ mm\)", report)) == 2
        )
    assert "4 claims in all" in report and "preregistered: 1 repetitions" in report
    assert {r["metric"] for r in stats_rows(tmp_path)} == CLAIMS | EFFECTS


@pytest.mark.slow
def test_both_designs_hold_each_trajectory_out_in_turn_and_the_count_is_preregistered(
    tmp_path: Path,
) -> None:
    generic_vs_specific.run(Experiment(tmp_path, in_process), BASE, reps=1)
    # The specific runs serve both designs; one generic run on every kind serves all three tests.
    assert len(list((tmp_path / "runs").iterdir())) == 2 * len(ALL_KINDS) + 1
    assert [t.kind for t in config(tmp_path, "generic-all-rep0").trajectories] == list(ALL_KINDS)
    for kind in ALL_KINDS:
        kinds = [t.kind for t in config(tmp_path, f"generic-no-{kind.value}-rep0").trajectories]
        assert kind not in kinds and len(kinds) == len(ALL_KINDS) - 1
        specific = config(tmp_path, f"specific-{kind.value}-rep0")
        assert [t.kind for t in specific.trajectories] == [kind]
    results = rows(tmp_path / "results.csv")
    assert len(results) == 2 * len(ALL_KINDS) * 2  # designs × test trajectories × controllers
    assert all(0 <= int(r["dominated_by_other"]) <= int(r["points"]) for r in results)
    found = stats_rows(tmp_path)
    claims = [r for r in found if r["metric"] in CLAIMS]
    assert len(claims) == 12 and {r["metric"] for r in found} == CLAIMS | EFFECTS
    # Effect sizes are estimates, not tests: no p-value to pick a finding from.
    assert all(r["p_value"] == "nan" for r in found if r["metric"] in EFFECTS)
    assert set(json.loads((tmp_path / "normalisation.json").read_text())) == {
        "on spiral",
        "on random",
        "on pyramid",
    }
    report = (tmp_path / "report.md").read_text()
    assert "12 claims in all" in report
    assert "every claim can reach p < 0.05 from 9 repetitions" in report
    assert json.loads((tmp_path / "preregistration.json").read_text()) == {
        "reps": 1,
        "designs": ["paper", "held-out"],
        "test_trajectories": ["spiral", "random", "pyramid"],
    }
    # No extension once the results are seen: another count or design is refused, nothing run.
    with pytest.raises(ValueError, match=r"^--reps: .* preregistered with reps 1, not 2"):
        generic_vs_specific.run(Experiment(tmp_path, in_process), BASE, reps=2)
    with pytest.raises(ValueError, match=r"^--design: .* optional stopping"):
        generic_vs_specific.run(Experiment(tmp_path, in_process), BASE, reps=1, designs=["paper"])
    assert len(list((tmp_path / "runs").iterdir())) == 2 * len(ALL_KINDS) + 1


def test_runs_from_before_preregistration_are_not_resumed(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    with pytest.raises(ValueError, match=r"^--out: .* before their number was preregistered"):
        generic_vs_specific.preregister(tmp_path, 5, ["paper"], list(ALL_KINDS))
    assert not (tmp_path / "preregistration.json").exists()


def test_the_preregistration_is_kept_when_resumed_alike(tmp_path: Path) -> None:
    generic_vs_specific.preregister(tmp_path / "new", 10, ["paper"], [TrajectoryKind.spiral])
    (tmp_path / "new" / "runs").mkdir()
    generic_vs_specific.preregister(tmp_path / "new", 10, ["paper"], [TrajectoryKind.spiral])
    with pytest.raises(ValueError, match=r"^--out: .* test trajectories"):
        generic_vs_specific.preregister(tmp_path / "new", 10, ["paper"], [TrajectoryKind.random])


@pytest.mark.parametrize(
    ("text", "designs"),
    [("both", ("paper", "held-out")), ("paper", ("paper",)), ("held-out", ("held-out",))],
)
def test_design_option(text: str, designs: tuple[str, ...]) -> None:
    assert generic_vs_specific.chosen_designs(text) == designs


@pytest.mark.slow
def test_an_unknown_design_is_one_line_naming_the_option(tmp_path: Path) -> None:
    assert refusal(tmp_path, "generic-vs-specific", "--design", "all").startswith(
        "--design: expected paper, held-out or both, got 'all'"
    )


@pytest.mark.parametrize("test", list(ALL_KINDS))
def test_the_held_out_generic_set_never_holds_the_test_trajectory(test: TrajectoryKind) -> None:
    kinds = [t.kind for t in generic_vs_specific.generic_set(test, 5.0)]
    assert test not in kinds and len(kinds) == len(ALL_KINDS) - 1


def test_the_table_gives_each_design_and_trajectorys_medians_and_effects() -> None:
    table = generic_vs_specific.table({("paper", "spiral"): (0.5, 0.25, -0.4, 1.25, 0.003)})
    assert table[0].startswith("| design | judged on | specific median hypervolume |")
    assert table[1] == "|---|---|---:|---:|---:|---:|---:|"
    assert table[2] == "| paper | spiral | 0.5000 | 0.2500 | -0.4 | +1.25 | +0.003 |"
