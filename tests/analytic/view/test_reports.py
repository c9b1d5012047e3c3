"""A run's report: the summary, the sorted front and the links; whole or not at all."""

import os
import re
from pathlib import Path

import pytest

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import Baseline, FrontMember
from gainfarm.analytic.view.export import picks
from gainfarm.analytic.view.reports import (
    DOMINATING_SHOWN,
    controllers_section,
    front_table_row,
    plant_text,
    recommendation_text,
    run_setup,
    run_title,
    write_report,
)
from gainfarm.models.ur5e import JOINT_NAMES as UR5E_JOINT_NAMES
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
    assert f"- stopped: {SAMPLE_CONVERGED}\n" in text
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
        converged="1 generation",  # a budget spent, as the termination says it
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "- generations: 1\n- evaluations: 30\n" in text and "- wall time: 12.5 s\n" in text
    assert "- stopped after 1 generation\n" in text and "1 generations" not in text
    assert "## Pareto front (1 member, most accurate first)" in text


def test_the_counts_of_one_are_singular_in_the_report(tmp_path: Path) -> None:
    from gainfarm.analytic.tuning.records import ValidationRecord
    from gainfarm.analytic.view.reports import validation_section

    once = ValidationRecord(
        refereed=2,
        spot_checked=1,
        spot_check_rate=0.05,
        disagreements=0,
        unsettled=0,
        distrusted={},
        rewinds=1,
        unchecked="",
    )
    lines = validation_section(once, [])
    assert lines[2] == (
        "- episodes the referee (this process) ran again: 2 of the front's, 1 spot check "
        "(rate 0.05)"
    )
    assert "started again 1 time without" in "\n".join(lines)


def test_the_report_says_every_check_and_what_the_spot_checks_rate_buys() -> None:
    from gainfarm.analytic.tuning.records import ValidationRecord
    from gainfarm.analytic.view.reports import validation_section

    guarantee = (
        "sized: a worker lying on 10% of its share of the run's episodes (72: 144 planned over "
        "2 workers) is caught with probability 0.99"
    )
    record = ValidationRecord(
        refereed=4,
        spot_checked=60,
        spot_check_rate=0.4725002936297381,
        spot_check_guarantee=guarantee,
        failures_checked=1,
        baseline_refereed=3,
        held_out_refereed=8,
        disagreements=1,
        distrusted={"w1": "failed job g0000-c001-t0 that the referee ran to scores"},
    )
    lines = validation_section(record, [])
    assert lines[2] == (
        "- episodes the referee (this process) ran again: 4 of the front's, 60 spot checks "
        "(rate 0.473), 1 failure its worker claimed, 3 episodes of the default gains', 8 "
        "episodes of the held-out check's"
    )
    assert f"- spot checks: {guarantee}" in lines
    assert (
        "- distrusted: w1, which failed job g0000-c001-t0 that the referee ran to scores" in lines
    )


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

    assert plant_text(REALISTIC_PLANT) == "iiwa14, realistic plant, flexible joints"
    assert plant_text(IDEAL_PLANT.model_copy(update={"joints": "rigid"})) == (
        "iiwa14, ideal plant, rigid joints"
    )
    custom = REALISTIC_PLANT.model_copy(update={"delay": 3})
    assert plant_text(custom).startswith("iiwa14, custom plant")


def test_the_report_names_the_controller_to_use_beside_the_default_gains(tmp_path: Path) -> None:
    front = [
        FrontMember(kp=KP, kd=KD, objectives=(0.005, 2.0)),
        FrontMember(kp=KP, kd=tuple(k * 2 for k in KD), objectives=(0.01, 0.3)),
        FrontMember(kp=KP, kd=tuple(k * 3 for k in KD), objectives=(0.01, 0.3)),  # the same point
        FrontMember(kp=tuple(k / 2 for k in KP), kd=KD, objectives=(0.05, 0.01)),
    ]
    baseline = Baseline(DEFAULT_GAINS, objectives=(0.02, 0.5), diverged=False)
    write_report(
        tmp_path / "report.md",
        title="t",
        config_lines=[],
        history=SAMPLE_HISTORY,
        front=front,
        converged="",
        picks=picks(front, baseline),
        baseline=baseline,
        run_dir="runs/r1",
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert text.splitlines()[2] == (
        "**Use front.csv row 2** (10.000 mm, f_t 0.3 (N·m)²): it dominates the default gains "
        "(20.000 mm, f_t 0.5 (N·m)²) on the run's trajectories, as accurate and as smooth and "
        "better in one, and is the knee among the members that do."
    )
    assert text.index("## The controller to use") < text.index("## Configuration")
    assert (
        "| **recommended** (use this) | 2 (2 members share it) | 10.000 | 0.3 | "
        "2000 2000 1200 1200 400 200 100 | 40 40 30 30 8 4 2 |" in text
    )
    assert "| knee of the whole front | 2 (2 members share it) | 10.000 | 0.3 |" in text
    assert (
        "| most accurate | 1 | 5.000 | 2 |" in text and "| smoothest | 4 | 50.000 | 0.01 |" in text
    )
    assert (
        "| default gains (not tuned) | – | 20.000 | 0.5 | 2000 2000 1200 1200 400 200 100 | "
        "20 20 15 15 4 2 1 |" in text
    )
    assert (
        "2 of the front's 4 members dominate the default gains:\n\n"
        "| front.csv row | f_acc (mm) | f_t ((N·m)²) |\n|---:|---:|---:|\n"
        "| 2 | 10.000 | 0.3 |\n| 3 | 10.000 | 0.3 |\n" in text
    )
    assert "The knee of the whole front" not in text  # it is one of them
    assert "`analytic export runs/r1`" in text and "pymoo's achievement scalarisation" in text
    # Members at one point are one line, saying how many share it.
    assert "## Pareto front (4 members, 3 distinct at the precision shown," in text
    table = text.split("## Pareto front")[1].splitlines()
    rows = [line for line in table if line.startswith("| ") and line[2].isdigit()]
    assert [row.split(" | ")[:4] for row in rows] == [
        ["| 1", "5.000", "2", "1"],
        ["| 2", "10.000", "0.3", "2 (rows 2-3)"],
        ["| 4", "50.000", "0.01", "1"],
    ]


def test_a_run_whose_front_never_dominates_the_defaults_says_so_in_its_first_line(
    tmp_path: Path,
) -> None:
    # The knee (row 2) is 30 % less accurate than the defaults; row 1 is 5 times rougher.
    front = [
        FrontMember(kp=KP, kd=KD, objectives=(0.010, 2.5)),
        FrontMember(kp=KP, kd=tuple(k * 2 for k in KD), objectives=(0.0186, 0.3)),
        FrontMember(kp=tuple(k / 2 for k in KP), kd=KD, objectives=(0.05, 0.01)),
    ]
    baseline = Baseline(DEFAULT_GAINS, objectives=(0.0143, 0.5), diverged=False)
    write_report(
        tmp_path / "report.md",
        title="t",
        config_lines=[],
        history=SAMPLE_HISTORY,
        front=front,
        converged="",
        picks=picks(front, baseline),
        baseline=baseline,
    )
    text = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert text.splitlines()[2] == (
        "**No member of the front dominates the default gains** (14.300 mm, f_t 0.5 (N·m)²) on "
        "the run's trajectories, so none is recommended: keep the default gains, or run longer "
        "(more evaluations, a larger population). Closest to dominating them: row 2 (18.600 mm, "
        "f_t 0.3 (N·m)²), whose worse objective is 1.30 times the defaults' (the least of any "
        "member)."
    )
    assert "use this" not in text and "**recommended**" not in text
    assert "| closest to dominating the defaults (not recommended) | 2 | 18.600 | 0.3 |" in text
    assert "members dominate the default gains" not in text  # no list of none


def test_the_first_line_when_the_defaults_diverged_or_were_not_scored() -> None:
    front = [
        FrontMember(kp=KP, kd=KD, objectives=(0.002, 4e4), diverged=True),
        FrontMember(kp=KP, kd=KD, objectives=(0.03, 0.6)),
    ]
    fell = Baseline(DEFAULT_GAINS, objectives=(10.0, 1e12), diverged=True)
    assert recommendation_text(picks(front, fell), fell).startswith(
        "**Use front.csv row 2** (30.000 mm, f_t 0.6 (N·m)²): the default gains diverged"
    )
    assert recommendation_text(picks(front), None) == (
        "**The default gains were not scored for this run** (no baseline.json), so no member is "
        "known to beat them and none is recommended; the knee of the front is row 2."
    )


def test_the_members_that_dominate_the_defaults_are_listed_the_first_ten_and_a_count() -> None:
    front = [
        FrontMember(kp=KP, kd=KD, objectives=(0.001 * (n + 1), 1.0 / (n + 1))) for n in range(25)
    ]
    # Rows 3-22 dominate (20 of them): f_acc at most 22 mm, f_t at most 1/3.
    baseline = Baseline(DEFAULT_GAINS, objectives=(0.0225, 0.34), diverged=False)
    lines = controllers_section(picks(front, baseline), baseline, "RUN", front)
    assert "20 of the front's 25 members dominate the default gains:" in lines
    listed = [line for line in lines if re.match(r"\| \d+ \| [\d.]+ \| ", line)]
    assert [line.split(" | ")[0] for line in listed] == [f"| {row}" for row in range(3, 13)]
    assert len(listed) == DOMINATING_SHOWN
    assert "and 10 more, between rows 13 and 22." in lines
    # The knee of the whole front, row 5, is one of them; with defaults it loses to, it says so.
    stricter = Baseline(DEFAULT_GAINS, objectives=(0.003, 1.0), diverged=False)
    lines = controllers_section(picks(front, stricter), stricter, "RUN", front)
    assert any(line.startswith("The knee of the whole front (row 5) is not one") for line in lines)


def test_a_runs_title_says_what_it_was_tuned_on() -> None:
    generic = RunConfig(
        pop=16,
        trajectories=(TrajectorySpec(duration=3.0), TrajectorySpec(kind="pyramid", duration=3.0)),
    )
    assert run_title(generic).startswith(
        "generic controller on spiral, pyramid 3 s, iiwa14, realistic plant, flexible joints, "
        "population 16\n"
    )
    mixed = RunConfig(
        trajectories=(TrajectorySpec(duration=3.0), TrajectorySpec(kind="random", duration=4.0)),
        plant=PLANTS["ideal"],
    )
    assert (
        "on spiral 3 s, random 4 s, iiwa14, ideal plant, flexible joints, population 30"
        in run_title(mixed)
    )


def test_the_damping_table_numbers_its_rows_as_front_csv_does() -> None:
    from gainfarm.analytic.view.run_report import damping_section
    from gainfarm.schemas.limits import Limits

    lines = damping_section(SAMPLE_FRONT, Limits())
    rows = [line.split(" | ")[0] for line in lines if line[:3] in ("| 1", "| 2", "| 3", "| 0")]
    assert rows == ["| 1", "| 2", "| 3"]


def test_a_check_cut_by_its_budget_says_how_many_plants_of_those_asked_and_why() -> None:
    from gainfarm.analytic.tuning.check import CheckPlan
    from gainfarm.analytic.view.run_report import check_section, check_start_line, held_out_lines

    item = {
        "name": "recommended",
        "row": 14,
        "nominal_f_acc": 0.004,
        "nominal_f_t": 0.1,
        "nominal_failed": False,
        "median_f_acc": 0.0061,
        "worst_f_acc": 0.01204,
        "violations": 12,
        "diverged": 0,
    }
    default = {**item, "name": "default gains", "row": None, "median_f_acc": 0.0065}
    cut = {"plants": 37, "asked": 64, "controllers": [item, default], "cost": {"episodes": 1}}
    text = "\n".join(check_section(cut))
    assert (
        "on the nominal plant and on 37 of the 64 held-out plants asked (the check may take at "
        "most half the run's own episodes), drawn" in text
    )
    assert "It cost 1 episode, ? s." in text
    assert "| recommended | 14 | 4.00 | 0.1 | 6.10 | 12.04 | 12 | 0 | – | – | – | – |" in text
    assert held_out_lines(cut, 14) == [
        "held out, on 37 of the 64 plants asked: error 6.10 mm median, 12.04 mm worst",
        "  (default gains: 6.50 mm, 12.04 mm)",
        "  (the check may take at most half the run's own episodes)",
        "held out: 12 plants broke a limit, 0 diverged",
    ]
    assert held_out_lines(cut, 3) == []  # not a controller the check ran
    whole = {"plants": 1, "asked": 1, "controllers": [{**item, "violations": 1}]}
    assert "on the nominal plant and on 1 held-out plant, drawn" in "\n".join(check_section(whole))
    assert held_out_lines(whole, 14)[-1] == "held out: 1 plant broke a limit, 0 diverged"
    assert check_start_line(CheckPlan(episodes=6, plants=1, asked=64, controllers=3)) == (
        "held-out check: 6 episodes on 1 of the 64 held-out plants asked"
    )
    for line in held_out_lines(cut, 14):
        assert len(line) <= 80, line  # the terminal's closing lines, as test_cli's live line


UR5E_JOINTS = UR5E_JOINT_NAMES


def test_a_ur5e_report_names_its_arm_its_joints_and_its_torque_interface(tmp_path: Path) -> None:
    """A run of the UR5e (6 joints): its report's setup names the arm and what its controller
    does with a torque command; its tables and units its joints, not the iiwa's."""
    config = RunConfig(plant=PLANTS["realistic"].model_copy(update={"robot": "ur5e"}))
    setup = run_setup(config)
    assert setup[2].startswith("ur5e, realistic plant, flexible joints")
    assert setup[3].startswith(
        "arm ur5e: 6 joints (shoulder_pan_joint..wrist_3_joint), behind UR direct torque "
        "control (URScript direct_torque"
    )
    assert setup[3].endswith("simulated adding its own gravity model under the command")
    assert "iiwa" not in " ".join(setup) and "KUKA" not in " ".join(setup)
    plain = config.model_copy(
        update={"plant": config.plant.model_copy(update={"interface": "torque"})}
    )
    assert run_setup(plain)[3].endswith("without gravity compensation (interface torque: the "
                                        "command is the motor torque)")  # fmt: skip
    six = (1000.0, 1000.0, 1000.0, 187.0, 187.0, 187.0)
    front = [
        FrontMember(kp=six, kd=tuple(k / 100 for k in six), objectives=(0.001 * n, 1.0 / n))
        for n in (1, 2, 3)
    ]
    write_report(
        tmp_path / "report.md",
        title="a UR5e run",
        config_lines=setup,
        history=SAMPLE_HISTORY,
        front=front,
        converged=SAMPLE_CONVERGED,
        picks=picks(front),
        joints=UR5E_JOINTS,
    )
    text = (tmp_path / "report.md").read_text()
    assert "kp (N·m/rad) shoulder_pan_joint..wrist_3_joint | kd" in text  # the picks' table
    assert "kd (N·m·s/rad), shoulder_pan_joint..wrist_3_joint |" in text  # the front's
    assert "one per joint shoulder_pan_joint..wrist_3_joint; f_acc" in text  # the units
    assert "A1" not in text and "A7" not in text
    assert "| 1000 1000 1000 187 187 187 | 10 10 10 1.87 1.87 1.87 |" in text
