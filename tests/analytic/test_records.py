"""A run's records: CSVs and JSON that read back exactly, a run read from its plain files."""

from pathlib import Path

import numpy as np
import pytest

from analytic.records import (
    FRONT_FIELDS,
    HISTORY_FIELDS,
    FrontMember,
    HistoryRow,
    front_csv,
    history_csv,
    read_front,
    read_history,
)
from tests.helpers import KD, KP, SAMPLE_FRONT, SAMPLE_HISTORY


def test_csvs_round_trip_exactly(tmp_path: Path) -> None:
    (tmp_path / "history.csv").write_bytes(history_csv(SAMPLE_HISTORY))
    (tmp_path / "front.csv").write_bytes(front_csv(SAMPLE_FRONT))
    assert read_history(tmp_path / "history.csv") == list(SAMPLE_HISTORY)
    front = read_front(tmp_path / "front.csv")
    assert sorted(front, key=lambda m: m.f_acc) == front  # sorted by f_acc in the file
    assert set(front) == set(SAMPLE_FRONT)
    header = (tmp_path / "front.csv").read_text().splitlines()[0]
    assert header == ",".join(FRONT_FIELDS) and len(FRONT_FIELDS) == 16
    assert history_csv(SAMPLE_HISTORY).decode().splitlines()[0] == ",".join(HISTORY_FIELDS)


def test_equal_fronts_give_byte_identical_csvs_whatever_the_order_and_number_type() -> None:
    as_numpy = [
        FrontMember(kp=np.array(m.kp), kd=np.array(m.kd), f_acc=np.float64(m.f_acc), f_t=m.f_t)
        for m in reversed(SAMPLE_FRONT)
    ]
    assert front_csv(as_numpy) == front_csv(SAMPLE_FRONT) == front_csv(list(SAMPLE_FRONT))
    assert b"np.float64" not in front_csv(as_numpy)
    history = [
        HistoryRow(
            np.int64(r.generation),
            r.evaluations,
            *map(np.float64, (r.hypervolume, r.best_f_acc, r.best_f_t, r.wall_seconds)),
        )
        for r in SAMPLE_HISTORY
    ]
    assert history_csv(history) == history_csv(SAMPLE_HISTORY)


def test_ties_in_both_objectives_are_ordered_by_the_gains() -> None:
    a = FrontMember(kp=KP, kd=KD, f_acc=0.01, f_t=1.0)
    b = FrontMember(kp=tuple(k + 1 for k in KP), kd=KD, f_acc=0.01, f_t=1.0)
    assert front_csv([a, b]) == front_csv([b, a])


def test_a_member_needs_seven_gains_of_each_kind() -> None:
    with pytest.raises(ValueError, match="kd needs 7"):
        FrontMember(kp=KP, kd=KD[:6], f_acc=0.01, f_t=1.0)


def test_reading_a_csv_of_another_format_is_refused(tmp_path: Path) -> None:
    (tmp_path / "history.csv").write_bytes(front_csv(SAMPLE_FRONT))
    with pytest.raises(ValueError, match="expected columns"):
        read_history(tmp_path / "history.csv")
