"""The generic-against-specific experiment at toy size: on a real local farm, and in this
process."""

import json
from pathlib import Path

import pytest

from gainfarm.analytic.experiments import generic_vs_specific
from gainfarm.analytic.experiments.base import ALL_KINDS, Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import balancing_weights, score
from gainfarm.schemas.trajectory import TrajectoryKind
from tests.analytic.experiments.common import (
    BASE,
    PNG,
    in_process,
    on_farm,
    rows,
    stats_rows,
)


@pytest.mark.slow
def test_generic_vs_specific(tmp_path: Path, endpoints: list[str]) -> None:
    generic_vs_specific.run(
        Experiment(tmp_path, on_farm(endpoints)), BASE, reps=1, kinds=[TrajectoryKind.pyramid]
    )
    results = rows(tmp_path / "results.csv")
    assert [(r["test_trajectory"], r["controller"]) for r in results] == [
        ("pyramid", "generic"),
        ("pyramid", "specific"),
    ]
    generic = (tmp_path / "runs" / "generic-no-pyramid-rep0" / "config.json").read_text()
    assert generic.count('"kind"') == 2 and "pyramid" not in generic  # held out
    # Balanced by the default gains' own episodes on the generic set, read back from their logs.
    defaults = []
    for kind in ("spiral", "random"):
        [log] = (tmp_path / "cross" / f"default-gains-on-{kind}" / "episodes").glob("*.mcap")
        found = score(read_episode(log))
        defaults.append((found.f_acc, found.f_t))
    weights = RunConfig.model_validate_json(generic).objective_weights
    assert weights == balancing_weights(defaults)
    cross = tmp_path / "cross" / "generic-no-pyramid-rep0-on-pyramid" / "episodes"
    assert len(list(cross.glob("*.mcap"))) >= 1
    assert (tmp_path / "generic-vs-specific.png").read_bytes().startswith(PNG)
    report = (tmp_path / "report.md").read_text()
    assert "on the pyramid (held out of the generic set): cannot decide" in report
    assert "generic points" in report
    assert {r["metric"] for r in stats_rows(tmp_path)} == {
        "hypervolume",
        "best_f_acc",
        "dominated_share",
    }
    assert "By dominance, paired by repetition: cannot decide" in report  # 1 pair


@pytest.mark.slow
def test_generic_vs_specific_holds_each_trajectory_out_in_turn(tmp_path: Path) -> None:
    generic_vs_specific.run(Experiment(tmp_path, in_process), BASE, reps=1)
    for kind in ALL_KINDS:
        generic = json.loads(
            (tmp_path / "runs" / f"generic-no-{kind.value}-rep0" / "config.json").read_text()
        )
        kinds = [trajectory["kind"] for trajectory in generic["trajectories"]]
        assert kind.value not in kinds and len(kinds) == 2
        specific = json.loads(
            (tmp_path / "runs" / f"specific-{kind.value}-rep0" / "config.json").read_text()
        )
        assert [trajectory["kind"] for trajectory in specific["trajectories"]] == [kind.value]
    results = rows(tmp_path / "results.csv")
    assert {r["test_trajectory"] for r in results} == {kind.value for kind in ALL_KINDS}
    assert all(0 <= int(r["dominated_by_other"]) <= int(r["points"]) for r in results)
    assert len(stats_rows(tmp_path)) == 9
    assert {r["metric"] for r in stats_rows(tmp_path)} == {
        "hypervolume",
        "best_f_acc",
        "dominated_share",
    }
    assert set(json.loads((tmp_path / "normalisation.json").read_text())) == {
        "on spiral",
        "on random",
        "on pyramid",
    }


@pytest.mark.parametrize("test", list(ALL_KINDS))
def test_the_generic_set_never_holds_the_test_trajectory(test: TrajectoryKind) -> None:
    kinds = [t.kind for t in generic_vs_specific.generic_set(test, 5.0)]
    assert test not in kinds and len(kinds) == len(ALL_KINDS) - 1


def test_the_table_gives_each_held_out_trajectorys_medians() -> None:
    medians = {("spiral", "specific"): 0.5, ("spiral", "generic"): 0.25}
    assert generic_vs_specific.table(medians) == [
        "| judged on | specific median hypervolume | generic median hypervolume |",
        "|---|---:|---:|",
        "| spiral | 0.5000 | 0.2500 |",
    ]
