"""A run's figures, report and CSVs: whole files, exact numbers, no crash on little data."""

import os
import struct
from pathlib import Path

import numpy as np
import pytest

from analytic.figures import (
    FRONT_FIELDS,
    HISTORY_FIELDS,
    FrontMember,
    HistoryRow,
    front_csv,
    front_table_row,
    history_csv,
    plot_hypervolume,
    plot_pareto,
    read_front,
    read_history,
    write_report,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
KP = (2000.0, 2000.0, 1200.0, 1200.0, 400.0, 200.0, 100.0)
KD = (20.0, 20.0, 15.0, 15.0, 4.0, 2.0, 1.0)

# Deliberately out of order, with values that a rounded format would not round-trip.
FRONT = (
    FrontMember(kp=KP, kd=KD, f_acc=0.0123456789012345, f_t=0.1 + 0.2),
    FrontMember(kp=tuple(k / 3 for k in KP), kd=KD, f_acc=0.045, f_t=1e-3 / 7),
    FrontMember(kp=tuple(k * 1.5 for k in KP), kd=tuple(k / 7 for k in KD), f_acc=0.002, f_t=4.2e4),
)
HISTORY = (
    HistoryRow(1, 30, 0.5, 0.05, 10.0, 12.5),
    HistoryRow(2, 60, 0.75 + 1e-12, 0.01, 1.0, 3700.25),
    HistoryRow(3, 90, 0.8, 0.002, 1e-3 / 7, 7300.0),
)
CONVERGED = "converged after 90 evaluations (hypervolume gain < 0.1% over 3 generations)"


def assert_png(path: Path) -> None:
    content = path.read_bytes()
    assert content.startswith(PNG_MAGIC)
    assert 5_000 < len(content) < 2_000_000
    width, height = struct.unpack(">II", content[16:24])  # the IHDR chunk
    assert (width, height) == (840, 600)


def leftovers(directory: Path) -> list[Path]:
    return [path for path in directory.iterdir() if path.name.endswith(".part")]


def test_pareto_and_hypervolume_figures_are_pngs(tmp_path: Path) -> None:
    evaluated = [(m.f_acc, m.f_t) for m in FRONT] + [(0.05, 1e3), (0.2, 5e5), (0.03, 2.0)]
    plot_pareto(tmp_path / "pareto.png", FRONT, evaluated, title="spiral, pop 30")
    plot_hypervolume(tmp_path / "hypervolume.png", HISTORY, title="spiral, pop 30")
    assert_png(tmp_path / "pareto.png")
    assert_png(tmp_path / "hypervolume.png")
    assert leftovers(tmp_path) == []


def test_figures_survive_no_data_one_generation_and_unloggable_values(tmp_path: Path) -> None:
    plot_pareto(tmp_path / "empty.png", [])
    plot_hypervolume(tmp_path / "none.png", [])
    plot_hypervolume(tmp_path / "one.png", HISTORY[:1])
    odd = [FrontMember(kp=KP, kd=KD, f_acc=0.01, f_t=0.0)]
    plot_pareto(tmp_path / "odd.png", odd, [(0.02, -1.0), (float("nan"), 1.0), (0.03, np.inf)])
    plot_pareto(tmp_path / "zero.png", odd, [(0.02, 0.0)])  # nothing positive: linear axis
    for name in ("empty", "none", "one", "odd", "zero"):
        assert_png(tmp_path / f"{name}.png")


def test_csvs_round_trip_exactly(tmp_path: Path) -> None:
    (tmp_path / "history.csv").write_bytes(history_csv(HISTORY))
    (tmp_path / "front.csv").write_bytes(front_csv(FRONT))
    assert read_history(tmp_path / "history.csv") == list(HISTORY)
    front = read_front(tmp_path / "front.csv")
    assert sorted(front, key=lambda m: m.f_acc) == front  # sorted by f_acc in the file
    assert set(front) == set(FRONT)
    header = (tmp_path / "front.csv").read_text().splitlines()[0]
    assert header == ",".join(FRONT_FIELDS) and len(FRONT_FIELDS) == 16
    assert history_csv(HISTORY).decode().splitlines()[0] == ",".join(HISTORY_FIELDS)


def test_equal_fronts_give_byte_identical_csvs_whatever_the_order_and_number_type() -> None:
    as_numpy = [
        FrontMember(kp=np.array(m.kp), kd=np.array(m.kd), f_acc=np.float64(m.f_acc), f_t=m.f_t)
        for m in reversed(FRONT)
    ]
    assert front_csv(as_numpy) == front_csv(FRONT) == front_csv(list(FRONT))
    assert b"np.float64" not in front_csv(as_numpy)
    history = [
        HistoryRow(
            np.int64(r.generation),
            r.evaluations,
            *map(np.float64, (r.hypervolume, r.best_f_acc, r.best_f_t, r.wall_seconds)),
        )
        for r in HISTORY
    ]
    assert history_csv(history) == history_csv(HISTORY)


def test_ties_in_both_objectives_are_ordered_by_the_gains() -> None:
    a = FrontMember(kp=KP, kd=KD, f_acc=0.01, f_t=1.0)
    b = FrontMember(kp=tuple(k + 1 for k in KP), kd=KD, f_acc=0.01, f_t=1.0)
    assert front_csv([a, b]) == front_csv([b, a])


def test_a_member_needs_seven_gains_of_each_kind() -> None:
    with pytest.raises(ValueError, match="kd needs 7"):
        FrontMember(kp=KP, kd=KD[:6], f_acc=0.01, f_t=1.0)


def test_reading_a_csv_of_another_format_is_refused(tmp_path: Path) -> None:
    (tmp_path / "history.csv").write_bytes(front_csv(FRONT))
    with pytest.raises(ValueError, match="expected columns"):
        read_history(tmp_path / "history.csv")


def test_report_holds_the_summary_the_sorted_table_and_the_links(tmp_path: Path) -> None:
    write_report(
        tmp_path / "report.md",
        title="spiral, 6 s",
        config_lines=["population 30", "trajectory spiral, 6 s"],
        history=HISTORY,
        front=FRONT,
        converged=CONVERGED,
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert text.startswith("# spiral, 6 s\n")
    assert "- population 30\n- trajectory spiral, 6 s\n" in text
    assert "- generations: 3\n- evaluations: 90\n- final hypervolume: 0.8\n" in text
    assert "- wall time: 2 h 01 min\n" in text
    assert f"- {CONVERGED}\n" in text
    rows = [line for line in text.splitlines() if line.startswith("| ") and line[2].isdigit()]
    assert rows == [
        "| 1 | 2.000 | 4.2e+04 | kp 3000 3000 1800 1800 600 300 150 / kd 2.857 2.857 2.143 2.143 "
        "0.5714 0.2857 0.1429 |",
        "| 2 | 12.346 | 0.3 | kp 2000 2000 1200 1200 400 200 100 / kd 20 20 15 15 4 2 1 |",
        "| 3 | 45.000 | 0.0001429 | kp 666.7 666.7 400 400 133.3 66.67 33.33 "
        "/ kd 20 20 15 15 4 2 1 |",
    ]
    assert rows[1] == front_table_row(2, FRONT[0])
    for link in ("](pareto.png)", "](hypervolume.png)", "](front.csv)", "](history.csv)"):
        assert link in text


def test_report_of_a_run_with_nothing_yet_says_so(tmp_path: Path) -> None:
    write_report(
        tmp_path / "report.md",
        title="t",
        config_lines=[],
        history=[],
        front=[],
        converged="stopped after 0 generations",
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "no generation finished yet" in text and "No members yet." in text
    assert "- stopped after 0 generations\n" in text and "](pareto.png)" in text


def test_a_single_generation_report(tmp_path: Path) -> None:
    write_report(
        tmp_path / "report.md",
        title="t",
        config_lines=["pop 30"],
        history=HISTORY[:1],
        front=FRONT[:1],
        converged="stopped after 1 generation",
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "- generations: 1\n- evaluations: 30\n" in text and "- wall time: 12.5 s\n" in text


def test_a_write_into_a_missing_directory_raises_and_creates_nothing(tmp_path: Path) -> None:
    missing = tmp_path / "missing"
    with pytest.raises(FileNotFoundError):
        plot_pareto(missing / "pareto.png", FRONT)
    with pytest.raises(FileNotFoundError):
        write_report(
            missing / "report.md", title="t", config_lines=[], history=[], front=[], converged=""
        )
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_leaves_no_temporary_file_and_the_old_file_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The target is a directory: the temporary file is written, then the rename fails.
    (tmp_path / "pareto.png").mkdir()
    with pytest.raises(OSError):
        plot_pareto(tmp_path / "pareto.png", FRONT)
    assert leftovers(tmp_path) == [] and (tmp_path / "pareto.png").is_dir()

    # The rename fails over an earlier report: the earlier one stays as it was.
    report = tmp_path / "report.md"
    report.write_text("earlier report\n")

    def failing_replace(source: str | os.PathLike, target: str | os.PathLike) -> None:
        raise OSError("disk gone")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk gone"):
        write_report(report, title="t", config_lines=[], history=HISTORY, front=FRONT, converged="")
    monkeypatch.undo()
    assert report.read_text() == "earlier report\n" and leftovers(tmp_path) == []
