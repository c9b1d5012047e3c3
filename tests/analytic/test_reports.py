"""A run's report: the summary, the sorted front and the links; whole or not at all."""

import os
from pathlib import Path

import pytest

from analytic.reports import front_table_row, plant_text, write_report
from tests.analytic.samples import SAMPLE_CONVERGED, SAMPLE_FRONT, SAMPLE_HISTORY, leftovers


def test_report_holds_the_summary_the_sorted_table_and_the_links(tmp_path: Path) -> None:
    write_report(
        tmp_path / "report.md",
        title="spiral, 6 s",
        config_lines=["population 30", "trajectory spiral, 6 s"],
        history=SAMPLE_HISTORY,
        front=SAMPLE_FRONT,
        converged=SAMPLE_CONVERGED,
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert text.startswith("# spiral, 6 s\n")
    assert "- population 30\n- trajectory spiral, 6 s\n" in text
    assert "- generations: 3\n- evaluations: 90\n- final hypervolume: 0.8\n" in text
    assert "- wall time: 2 h 01 min\n" in text
    assert f"- {SAMPLE_CONVERGED}\n" in text
    rows = [line for line in text.splitlines() if line.startswith("| ") and line[2].isdigit()]
    assert rows == [
        "| 1 | 2.000 | 4.2e+04 | kp 3000 3000 1800 1800 600 300 150 / kd 2.857 2.857 2.143 2.143 "
        "0.5714 0.2857 0.1429 |",
        "| 2 | 12.346 | 0.3 | kp 2000 2000 1200 1200 400 200 100 / kd 20 20 15 15 4 2 1 |",
        "| 3 | 45.000 | 0.0001429 | kp 666.7 666.7 400 400 133.3 66.67 33.33 "
        "/ kd 20 20 15 15 4 2 1 |",
    ]
    assert rows[1] == front_table_row(2, SAMPLE_FRONT[0])
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
        history=SAMPLE_HISTORY[:1],
        front=SAMPLE_FRONT[:1],
        converged="stopped after 1 generation",
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "- generations: 1\n- evaluations: 30\n" in text and "- wall time: 12.5 s\n" in text


def test_a_report_written_into_a_missing_directory_raises_and_creates_nothing(
    tmp_path: Path,
) -> None:
    missing = tmp_path / "missing"
    with pytest.raises(FileNotFoundError):
        write_report(
            missing / "report.md", title="t", config_lines=[], history=[], front=[], converged=""
        )
    assert list(tmp_path.iterdir()) == []


def test_a_failed_report_write_leaves_the_old_file_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The rename fails over an earlier report: the earlier one stays as it was.
    report = tmp_path / "report.md"
    report.write_text("earlier report\n")

    def failing_replace(source: str | os.PathLike, target: str | os.PathLike) -> None:
        raise OSError("disk gone")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk gone"):
        write_report(
            report,
            title="t",
            config_lines=[],
            history=SAMPLE_HISTORY,
            front=SAMPLE_FRONT,
            converged="",
        )
    monkeypatch.undo()
    assert report.read_text() == "earlier report\n" and leftovers(tmp_path) == []


def test_a_report_names_the_plant_it_was_simulated_on():
    from schemas.robot import IDEAL_PLANT, REALISTIC_PLANT

    assert plant_text(REALISTIC_PLANT) == "realistic plant, flexible joints"
    assert plant_text(IDEAL_PLANT.model_copy(update={"joints": "rigid"})) == (
        "ideal plant, rigid joints"
    )
    custom = REALISTIC_PLANT.model_copy(update={"delay": 3})
    assert plant_text(custom).startswith("custom plant")
