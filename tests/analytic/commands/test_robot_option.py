"""--robot on the tuning commands: a UR5e (6 joints) tuned end to end on a real local farm, and
the refusals of an arm that does not fit, each one line naming --robot."""

import csv
import json
import sys
from pathlib import Path

import pytest

from gainfarm.analytic.cli import main
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import read_front_json
from gainfarm.cli import interrupts
from gainfarm.models import robot_of
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.robot import PlantSpec
from tests.helpers import analytic


def _refused(monkeypatch: pytest.MonkeyPatch, capsys, cwd: Path, *arguments: str) -> str:
    """`analytic ARGUMENTS` in this process, for a command refused before any farm: its one
    line on stderr (its exit status checked non-zero)."""
    monkeypatch.chdir(cwd)
    monkeypatch.setattr(sys, "argv", ["analytic", *arguments])
    capsys.readouterr()
    try:
        with pytest.raises(SystemExit) as exit:
            main()
    finally:
        interrupts.uninstall()  # the command took Ctrl-C over for its process: give it back
    assert exit.value.code not in (0, None)
    said = capsys.readouterr().err.strip().splitlines()
    assert len(said) == 1, said
    return said[0]


@pytest.mark.slow
def test_a_ur5e_is_tuned_end_to_end_with_its_six_joints_in_every_record(tmp_path: Path) -> None:
    arm = robot_of("ur5e")
    run = analytic(
        "start",
        *("--robot", "ur5e", "--pop", "4", "--generations", "2"),
        *("--trajectory", "fourier", "--duration", "0.5", "--check-plants", "2"),
        *("--workers", "1", "--out", "run"),
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr
    directory = tmp_path / "run"
    with (directory / "front.csv").open() as stream:
        rows = list(csv.reader(stream))
    gains = [f"kp{j}" for j in range(1, 7)] + [f"kd{j}" for j in range(1, 7)]
    assert rows[0][:12] == gains and rows[0][12] != "kp7"
    assert rows[1:] and all(len(row) == len(rows[0]) for row in rows[1:])
    config = RunConfig.model_validate_json((directory / "config.json").read_text())
    assert config.robot == "ur5e" and config.trajectories[0].center == arm.workspace.center
    assert all(p.robot == "ur5e" and len(p.stiffness) == 6 for p in config.plants)
    assert all(p.robot == "ur5e" for p in config.check_plants)
    # The baseline and the check judge the run against the UR5e's default gains.
    baseline = json.loads((directory / "baseline.json").read_text())
    assert tuple(baseline["gains"]["kp"]) == arm.default_gains.kp
    check = json.loads((directory / "check.json").read_text())
    [default] = [c for c in check["controllers"] if c["name"] == "default gains"]
    assert tuple(default["kd"]) == arm.default_gains.kd
    members = read_front_json(directory / "front.json")
    assert members and all(len(m.kp) == 6 for m in members)
    log = read_episode(directory / members[0].logs[0])
    assert log.metadata.spec.plant.robot == "ur5e" and len(log.metadata.spec.gains.kp) == 6


def test_a_ur5e_batch_refuses_a_front_of_the_iiwa(monkeypatch, capsys, tmp_path: Path) -> None:
    header = [f"kp{j}" for j in range(1, 8)] + [f"kd{j}" for j in range(1, 8)] + ["f_acc", "f_t"]
    (tmp_path / "front.csv").write_text(",".join(header) + "\n" + ",".join(["1"] * 16) + "\n")
    said = _refused(
        monkeypatch, capsys, tmp_path, "batch", "--local", "--robot", "ur5e", "--gains", "front.csv"
    )
    assert said.endswith(
        "--gains: 'front.csv' is a front of a 7-joint arm, not of the 6 joints of --robot's "
        f"({', '.join(robot_of('ur5e').joint_names)})"
    )


def test_resume_refuses_another_arm_than_the_runs(monkeypatch, capsys, tmp_path: Path) -> None:
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.json").write_text(RunConfig(plant=PlantSpec()).model_dump_json())
    said = _refused(monkeypatch, capsys, tmp_path, "resume", "run", "--robot", "ur5e")
    assert said.endswith("--robot: ur5e, but the run in 'run' is of iiwa14")


def test_an_experiment_of_the_iiwa_by_design_refuses_another_arm(
    monkeypatch, capsys, tmp_path: Path
) -> None:
    said = _refused(
        monkeypatch, capsys, tmp_path, "experiment", "feedforward", "--robot", "ur5e", "--out", "x"
    )
    assert "--robot: feedforward runs on iiwa14 only, not ur5e: " in said
    assert not (tmp_path / "x").exists()
