"""A run's report: the summary, the sorted front and the links; whole or not at all."""

import os
from pathlib import Path

import pytest

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import Baseline, FrontMember
from gainfarm.analytic.view.export import picks
from gainfarm.analytic.view.reports import (
    baseline_text,
    front_table_row,
    plant_text,
    run_title,
    write_report,
)
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.trajectory import TrajectorySpec
from tests.analytic.samples import (
    KD,
    KP,
    SAMPLE_CONVERGED,
    SAMPLE_FRONT,
    SAMPLE_HISTORY,
    leftovers,
)


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
        "| 1 | 2.000 *diverged* | 4.2e+04 | 1 | kp 3000 3000 1800 1800 600 300 150 / kd 2.857 "
        "2.857 2.143 2.143 0.5714 0.2857 0.1429 |",
        "| 2 | 12.346 | 0.3 | 1 | kp 2000 2000 1200 1200 400 200 100 / kd 20 20 15 15 4 2 1 |",
        "| 3 | 45.000 | 0.0001429 | 1 | kp 666.7 666.7 400 400 133.3 66.67 33.33 "
        "/ kd 20 20 15 15 4 2 1 |",
    ]
    assert "*diverged*: an episode of the member was stopped early" in text  # why it says so
    assert "kp in N·m/rad and kd in N·m·s/rad" in text
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
    from gainfarm.schemas.robot import IDEAL_PLANT, REALISTIC_PLANT

    assert plant_text(REALISTIC_PLANT) == "realistic plant, flexible joints"
    assert plant_text(IDEAL_PLANT.model_copy(update={"joints": "rigid"})) == (
        "ideal plant, rigid joints"
    )
    custom = REALISTIC_PLANT.model_copy(update={"delay": 3})
    assert plant_text(custom).startswith("custom plant")


def test_the_report_names_the_controller_to_use_beside_the_default_gains(tmp_path: Path) -> None:
    front = [
        FrontMember(kp=KP, kd=KD, f_acc=0.005, f_t=2.0),
        FrontMember(kp=KP, kd=tuple(k * 2 for k in KD), f_acc=0.01, f_t=0.3),
        FrontMember(kp=KP, kd=tuple(k * 3 for k in KD), f_acc=0.01, f_t=0.3),  # the same point
        FrontMember(kp=tuple(k / 2 for k in KP), kd=KD, f_acc=0.05, f_t=0.01),
    ]
    baseline = Baseline(DEFAULT_GAINS, f_acc=0.02, f_t=0.5, diverged=False)
    write_report(
        tmp_path / "report.md",
        title="t",
        config_lines=[],
        history=SAMPLE_HISTORY,
        front=front,
        converged="",
        picks=picks(front),
        baseline=baseline,
        run_dir="runs/r1",
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert text.index("## The controller to use") < text.index("## Configuration")
    assert (
        "| **knee** (use this) | 2 (2 members share it) | 10.000 | 0.3 | "
        "2000 2000 1200 1200 400 200 100 | 40 40 30 30 8 4 2 |" in text
    )
    assert (
        "| most accurate | 1 | 5.000 | 2 |" in text and "| smoothest | 4 | 50.000 | 0.01 |" in text
    )
    assert (
        "| default gains (not tuned) | – | 20.000 | 0.5 | 2000 2000 1200 1200 400 200 100 | "
        "20 20 15 15 4 2 1 |" in text
    )
    assert "2 of the front's 4 members dominate the default gains" in text
    assert "`analytic export runs/r1`" in text and "pymoo's achievement scalarisation" in text
    # Members at one point are one line, saying how many share it.
    assert "## Pareto front (4 members, 3 distinct at the precision shown," in text
    rows = [line for line in text.splitlines() if line.startswith("| ") and line[2].isdigit()]
    assert [row.split(" | ")[:4] for row in rows] == [
        ["| 1", "5.000", "2", "1"],
        ["| 2", "10.000", "0.3", "2 (rows 2-3)"],
        ["| 4", "50.000", "0.01", "1"],
    ]


def test_the_report_says_when_the_default_gains_diverged_or_dominate_the_knee() -> None:
    front = [FrontMember(kp=KP, kd=KD, f_acc=0.03, f_t=0.6)]
    knee = picks(front)[0].member
    better = Baseline(DEFAULT_GAINS, f_acc=0.02, f_t=0.5, diverged=False)
    assert "the default gains dominate the knee" in baseline_text(front, better, knee)
    fell = Baseline(DEFAULT_GAINS, f_acc=10.0, f_t=1e12, diverged=True)
    assert "default gains diverged" in baseline_text(front, fell, knee)


def test_a_runs_title_says_what_it_was_tuned_on() -> None:
    generic = RunConfig(
        pop=16,
        trajectories=(TrajectorySpec(duration=3.0), TrajectorySpec(kind="pyramid", duration=3.0)),
    )
    assert run_title(generic).startswith(
        "generic controller on spiral, pyramid 3 s, realistic plant, flexible joints, "
        "population 16\n"
    )
    mixed = RunConfig(
        trajectories=(TrajectorySpec(duration=3.0), TrajectorySpec(kind="random", duration=4.0)),
        model=PLANTS["ideal"],
    )
    assert "on spiral 3 s, random 4 s, ideal plant, flexible joints, population 30" in run_title(
        mixed
    )
