"""A run's records: CSVs and JSON that read back exactly, a run read from its plain files."""

import json
import pickle
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from gainfarm import plugins
from gainfarm.analytic.tuning.declared import declarations
from gainfarm.analytic.tuning.records import (
    FRONT_FIELDS,
    HISTORY_FIELDS,
    FrontMember,
    HistoryRow,
    best_of,
    evaluated_csv,
    front_csv,
    front_json,
    history_csv,
    read_evaluated,
    read_front,
    read_front_json,
    read_history,
    read_measured,
    results_csv,
    sorted_front,
)
from gainfarm.schemas.limits import NOT_DAMPED, NOT_MEASURED, Limits
from gainfarm.schemas.objectives import MAXIMISE, Objective
from tests.analytic.samples import KD, KP, SAMPLE_FRONT, SAMPLE_HISTORY


def test_csvs_round_trip_exactly(tmp_path: Path) -> None:
    (tmp_path / "history.csv").write_bytes(history_csv(SAMPLE_HISTORY))
    (tmp_path / "front.csv").write_bytes(front_csv(SAMPLE_FRONT))
    assert read_history(tmp_path / "history.csv") == list(SAMPLE_HISTORY)
    front = read_front(tmp_path / "front.csv")
    assert sorted(front, key=lambda m: m.f_acc) == front  # sorted by f_acc in the file
    assert set(front) == set(SAMPLE_FRONT)
    header = (tmp_path / "front.csv").read_text().splitlines()[0]
    assert header == ",".join(FRONT_FIELDS) and len(FRONT_FIELDS) == 17
    assert [m.diverged for m in front] == [True, False, False]  # the sample's 0.002 m member
    assert history_csv(SAMPLE_HISTORY).decode().splitlines()[0] == ",".join(HISTORY_FIELDS)


def test_equal_fronts_give_byte_identical_csvs_whatever_the_order_and_number_type() -> None:
    as_numpy = [
        FrontMember(
            kp=np.array(m.kp),
            kd=np.array(m.kd),
            objectives=(np.float64(m.f_acc), m.f_t),
            diverged=m.diverged,
        )
        for m in reversed(SAMPLE_FRONT)
    ]
    assert front_csv(as_numpy) == front_csv(SAMPLE_FRONT) == front_csv(list(SAMPLE_FRONT))
    assert b"np.float64" not in front_csv(as_numpy)
    history = [
        HistoryRow(
            np.int64(r.generation),
            r.evaluations,
            np.float64(r.hypervolume),
            tuple(map(np.float64, r.best)),
            np.float64(r.wall_seconds),
        )
        for r in SAMPLE_HISTORY
    ]
    assert history_csv(history) == history_csv(SAMPLE_HISTORY)


def test_ties_in_both_objectives_are_ordered_by_the_gains() -> None:
    a = FrontMember(kp=KP, kd=KD, objectives=(0.01, 1.0))
    b = FrontMember(kp=tuple(k + 1 for k in KP), kd=KD, objectives=(0.01, 1.0))
    assert front_csv([a, b]) == front_csv([b, a])


def test_a_member_needs_one_gain_of_each_kind_per_joint() -> None:
    with pytest.raises(ValueError, match="kp has 7 gains and kd 6"):
        FrontMember(kp=KP, kd=KD[:6], objectives=(0.01, 1.0))
    with pytest.raises(ValueError, match="kp needs one gain per joint, got 0"):
        FrontMember(kp=(), kd=(), objectives=(0.01, 1.0))


def test_a_six_joint_front_is_written_and_read_with_its_own_columns(tmp_path: Path) -> None:
    six = [
        FrontMember(kp=KP[:6], kd=KD[:6], objectives=(0.01, 1.0)),
        FrontMember(kp=KP[1:], kd=KD[1:], objectives=(0.02, 0.5)),
    ]
    (tmp_path / "front.csv").write_bytes(front_csv(six))
    header = (tmp_path / "front.csv").read_text().splitlines()[0].split(",")
    assert header[:12] == [*(f"kp{j}" for j in range(1, 7)), *(f"kd{j}" for j in range(1, 7))]
    assert header[12:] == ["f_acc", "f_t", "diverged"]
    assert read_front(tmp_path / "front.csv") == six
    # An empty front says its robot's joint count in its header all the same.
    (tmp_path / "empty.csv").write_bytes(front_csv([], joints=6))
    assert (tmp_path / "empty.csv").read_text().startswith("kp1,kp2,kp3,kp4,kp5,kp6,kd1,")
    assert read_front(tmp_path / "empty.csv") == []


def test_reading_a_csv_of_another_format_is_refused(tmp_path: Path) -> None:
    (tmp_path / "history.csv").write_bytes(front_csv(SAMPLE_FRONT))
    with pytest.raises(ValueError, match="expected columns"):
        read_history(tmp_path / "history.csv")


def test_a_front_csv_from_before_the_diverged_column_still_reads(tmp_path: Path) -> None:
    lines = front_csv(SAMPLE_FRONT).decode().splitlines()
    legacy = [line.rsplit(",", 1)[0] for line in lines]  # the last column dropped
    (tmp_path / "front.csv").write_text("\n".join(legacy) + "\n")
    front = read_front(tmp_path / "front.csv")
    assert [m.objectives for m in front] == [m.objectives for m in sorted_front(SAMPLE_FRONT)]
    assert not any(m.diverged for m in front)


def test_a_diverged_flag_other_than_true_or_false_is_refused(tmp_path: Path) -> None:
    text = front_csv(SAMPLE_FRONT).decode().replace(",true\n", ",yes\n")
    (tmp_path / "front.csv").write_text(text)
    with pytest.raises(ValueError, match="diverged must be true or false, got 'yes'"):
        read_front(tmp_path / "front.csv")
    with pytest.raises(ValueError, match="diverged must be true or false"):
        FrontMember(kp=KP, kd=KD, objectives=(0.01, 1.0), diverged="false")  # type: ignore[arg-type]


def test_front_json_round_trips_with_each_members_logs(tmp_path: Path) -> None:
    front = [
        FrontMember(m.kp, m.kd, m.objectives, logs=(f"episodes/c{i}-t0.mcap",), diverged=m.diverged)
        for i, m in enumerate(SAMPLE_FRONT)
    ]
    (tmp_path / "front.json").write_bytes(front_json(front))
    read = read_front_json(tmp_path / "front.json")
    assert read == sorted_front(front)  # front.csv's order
    assert [m.logs for m in read] == [m.logs for m in sorted_front(front)]
    assert [m.diverged for m in read] == [m.diverged for m in sorted_front(front)]
    assert read == read_front(_csv(tmp_path, front))  # the same members as front.csv's


def _csv(directory: Path, front: list[FrontMember]) -> Path:
    (directory / "front.csv").write_bytes(front_csv(front))
    return directory / "front.csv"


def test_a_front_json_from_before_the_lag_reads_it_as_zero(tmp_path: Path) -> None:
    """Its members' measures name no lag: read in MEASURED's order with a lag of 0, the damping
    in its place; one from before the damping has none."""
    old = {"torque_step": 0.01, "saturated_fraction": 0.0, "speed": 0.5, "chatter": 0.001}
    members = [
        {"kp": list(KP), "kd": list(KD), "f_acc": 0.01, "f_t": 1.0, "measures": measures}
        for measures in (old | {"damping": -0.02}, old)
    ]
    (tmp_path / "front.json").write_text(json.dumps({"members": members}))
    damped, undamped = read_front_json(tmp_path / "front.json")
    assert damped.measures == (0.01, 0.0, 0.5, 0.001, 0.0, -0.02)
    assert undamped.measures == (0.01, 0.0, 0.5, 0.001, 0.0)
    again = json.loads(front_json([damped]))["members"][0]["measures"]
    assert again == old | {"lag": 0.0, "damping": -0.02}


def test_reading_a_front_json_of_another_format_is_refused(tmp_path: Path) -> None:
    for content in ("{not json", '{"front": []}', '{"members": [{"kp": [1]}]}'):
        (tmp_path / "front.json").write_text(content)
        with pytest.raises(ValueError, match=r"not a front\.json"):
            read_front_json(tmp_path / "front.json")


def test_evaluated_points_round_trip_exactly(tmp_path: Path) -> None:
    points = [(0.1 + 0.2, 1e-3 / 7), (0.0123456789012345, 4.2e4), (10.0, 1e12)]
    measured = [
        (0.01, 0.0, 0.5, 1e-3 / 3, 0.006, 0.05),
        (0.4, 0.3, 3.0, 0.7, 0.2, -0.2),
        (*NOT_MEASURED, NOT_DAMPED),
    ]
    path = tmp_path / "evaluated.csv"
    path.write_bytes(evaluated_csv(points, measured, Limits()))
    assert read_evaluated(path) == points
    assert read_measured(path) == measured
    lines = path.read_text().splitlines()
    assert lines[0] == (
        "f_acc,f_t,torque_step,saturated_fraction,speed,chatter,lag,damping,feasible"
    )
    assert [line.rsplit(",", 1)[1] for line in lines[1:]] == ["true", "false", "false"]
    # Limits from a file decide it: the first breaks a tighter torque step.
    path.write_bytes(evaluated_csv(points, measured, Limits(torque_step=0.005)))
    assert path.read_text().splitlines()[1].endswith(",false")


def test_evaluated_csv_from_before_the_damping_reads_its_measures(tmp_path: Path) -> None:
    path = tmp_path / "evaluated.csv"
    path.write_text(
        "f_acc,f_t,torque_step,saturated_fraction,speed,chatter,feasible\n"
        "0.01,2.5,0.01,0.0,0.5,0.001,true\n"
    )
    assert read_evaluated(path) == [(0.01, 2.5)]
    assert read_measured(path) == [(0.01, 0.0, 0.5, 0.001, 0.0)]  # no lag either: read as 0
    assert Limits(min_damping=0.1).violated(read_measured(path)[0]) == ()  # not judged


def test_evaluated_csv_from_before_the_lag_reads_it_as_zero(tmp_path: Path) -> None:
    path = tmp_path / "evaluated.csv"
    path.write_text(
        "f_acc,f_t,torque_step,saturated_fraction,speed,chatter,damping,feasible\n"
        "0.01,2.5,0.01,0.0,0.5,0.001,-0.02,true\n"
    )
    assert read_evaluated(path) == [(0.01, 2.5)]
    assert read_measured(path) == [(0.01, 0.0, 0.5, 0.001, 0.0, -0.02)]  # the damping in place
    assert Limits().violated(read_measured(path)[0]) == ()
    assert Limits(min_damping=0.0).violated(read_measured(path)[0]) == ("damping",)


def test_evaluated_csv_from_before_the_limits_reads_its_objectives(tmp_path: Path) -> None:
    path = tmp_path / "evaluated.csv"
    path.write_text("f_acc,f_t\n0.01,2.5\n")
    assert read_evaluated(path) == [(0.01, 2.5)]
    assert read_measured(path) == []


def test_results_csv_keeps_the_rows_columns_in_order() -> None:
    rows = [{"pop": 4, "rep": 0, "hypervolume": 0.5}, {"pop": 6, "rep": 1, "hypervolume": 0.25}]
    assert results_csv(rows).decode().splitlines() == [
        "pop,rep,hypervolume",
        "4,0,0.5",
        "6,1,0.25",
    ]


# --- objectives by name ------------------------------------------------------------------------

COMPLETION = Objective(
    name="completion",
    unit="1",
    direction=MAXIMISE,
    description="share of the planned ticks run",
    no_episode=-1.0,
    function=lambda log: log.ticks / log.metadata.ticks_planned,
)


@pytest.fixture
def completion() -> Iterator[Objective]:
    plugins.register(plugins.OBJECTIVES, "completion", COMPLETION)
    yield COMPLETION
    plugins.unregister(plugins.OBJECTIVES, "completion")


def test_a_run_of_other_objectives_names_its_columns_and_writes_a_maximised_one_as_it_is(
    tmp_path: Path, completion: Objective
) -> None:
    names = ("f_acc", "completion")
    # As the optimiser was told them: the maximised share negated.
    front = [
        FrontMember(kp=KP, kd=KD, objectives=(0.01, -0.9), names=names, maximised=("completion",)),
        FrontMember(
            kp=KP, kd=KD[::-1], objectives=(0.02, -1.0), names=names, maximised=("completion",)
        ),
    ]
    assert front[0].named == {"f_acc": 0.01, "completion": 0.9}
    with pytest.raises(AttributeError, match="objectives are f_acc, completion, not f_t"):
        front[0].f_t  # noqa: B018
    text = front_csv(front).decode()
    assert text.splitlines()[0].endswith(",f_acc,completion,diverged")
    assert text.splitlines()[1].endswith(",0.01,0.9,false")  # in its own sense
    (tmp_path / "front.csv").write_text(text)
    assert read_front(tmp_path / "front.csv") == front
    (tmp_path / "front.json").write_bytes(front_json(front))
    assert read_front_json(tmp_path / "front.json") == front
    limits = Limits()
    measured = [(0.1, 0.0, 0.1, 0.0, 0.01, NOT_DAMPED)] * 2
    (tmp_path / "evaluated.csv").write_bytes(
        evaluated_csv([(0.01, -0.9), (0.5, -0.2)], measured, limits, declarations(names))
    )
    assert (tmp_path / "evaluated.csv").read_text().startswith("f_acc,completion,torque_step,")
    assert read_evaluated(tmp_path / "evaluated.csv") == [(0.01, -0.9), (0.5, -0.2)]
    history = [HistoryRow(1, 4, 0.3, best_of([(0.01, -0.9), (0.5, -0.2)], names), 1.0, names)]
    assert history[0].best == (0.01, 0.9)  # the most completed, as it is
    (tmp_path / "history.csv").write_bytes(history_csv(history))
    assert (
        "generation,evaluations,hypervolume,best_f_acc,best_completion,wall_seconds"
        in (tmp_path / "history.csv").read_text()
    )
    assert read_history(tmp_path / "history.csv") == history


def test_a_run_whose_plugin_is_not_installed_here_still_reads(tmp_path: Path) -> None:
    names = ("f_acc", "jerk")
    front = [FrontMember(kp=KP, kd=KD, objectives=(0.01, 3.5), names=names)]
    (tmp_path / "front.csv").write_bytes(front_csv(front))
    read = read_front(tmp_path / "front.csv")
    assert read == front and read[0].named == {"f_acc": 0.01, "jerk": 3.5}
    (jerk,) = declarations(("jerk",))
    assert (jerk.unit, jerk.direction) == ("", "minimise") and "not installed" in jerk.description


def test_a_history_row_pickled_before_objectives_were_named_reads_back() -> None:
    row = SAMPLE_HISTORY[0]
    state = dict(row.__dict__)
    state["best_f_acc"], state["best_f_t"] = state.pop("best")
    del state["names"]
    old = HistoryRow.__new__(HistoryRow)
    old.__setstate__(state)
    assert old == row and (old.best_f_acc, old.best_f_t) == row.best
    assert pickle.loads(pickle.dumps(row)) == row
