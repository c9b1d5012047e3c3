"""--robot on the commands that read the arm from their input (`analytic export`, `validate`,
`replay`, `dashboard`): left out, the input's arm; given, the input must be of that arm, or the
command says so in one line naming --robot, exits 2 and writes nothing. Real subprocesses."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from gainfarm.analytic.commands.work import validate as validating
from gainfarm.analytic.tuning.records import FrontMember, front_csv
from gainfarm.models.ur5e import JOINT_NAMES as UR5E_JOINT_NAMES
from gainfarm.schemas.episode_log import EpisodeLog
from tests.analytic.samples import KD, KP
from tests.helpers import analytic, write_log

UR5E_JOINTS = list(UR5E_JOINT_NAMES)


def iiwa_run(directory: Path) -> Path:
    """A run of the iiwa 14 as a run leaves it, written by hand: config, front, history."""
    directory.mkdir()
    (directory / "config.json").write_text('{"pop": 8, "generations": 3}')
    front = [
        FrontMember(
            kp=tuple(k * (1 + n / 10) for k in KP),
            kd=KD,
            objectives=(0.01 * (n + 1), 1.0 / (n + 1)),
        )
        for n in range(3)
    ]
    (directory / "front.csv").write_bytes(front_csv(front))
    (directory / "history.csv").write_text(
        "generation,evaluations,hypervolume,best_f_acc,best_f_t,wall_seconds\n"
        "1,8,0.5,0.01,0.1,1.0\n2,16,0.6,0.01,0.05,2.0\n3,24,0.7,0.01,0.05,3.0\n"
    )
    return directory


def test_an_input_of_another_arm_is_refused_in_one_line(
    tmp_path: Path, tracking_log: EpisodeLog
) -> None:
    run = iiwa_run(tmp_path / "run")
    log = tmp_path / "iiwa.mcap"
    write_log(tracking_log, log)  # an episode of the iiwa 14
    twin = tmp_path / "twin.toml"
    twin.write_text('[plant]\nrobot = "iiwa14"\n')
    cases = {
        ("export", str(run), "--member", "1", "--robot", "ur5e"): (
            f"--robot: {str(run)!r} is a run of iiwa14, not of ur5e"
        ),
        ("replay", str(log), "--out", str(tmp_path / "v.mp4"), "--robot", "ur5e"): (
            f"--robot: {str(log)!r} is an episode of iiwa14, not of ur5e"
        ),
        ("validate", str(twin), str(log), "--local", "--robot", "ur5e", "--out", "v"): (
            f"--robot: TWIN {str(twin)!r} is a twin of iiwa14, not of ur5e"
        ),
        ("dashboard", "--robot", "kuka"): "'kuka' is no robot here",
    }
    before = sorted(os.listdir(tmp_path))
    for arguments, says in cases.items():
        done = analytic(*arguments, cwd=tmp_path)
        assert done.returncode == 2, (arguments, done.stderr)
        assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
        assert says in done.stderr, done.stderr
    assert sorted(os.listdir(tmp_path)) == before


def test_the_input_s_own_arm_is_the_default_and_may_be_named(tmp_path: Path) -> None:
    run = iiwa_run(tmp_path / "run")
    for named in ((), ("--robot", "iiwa14")):
        done = analytic(
            "export", str(run), "--member", "1", "--format", "yaml", *named, cwd=tmp_path
        )
        assert done.returncode == 0, done.stderr
        exported = yaml.safe_load(done.stdout)
        assert exported["joints"] == [f"A{k}" for k in range(1, 8)]
        assert exported["assumes"]["torque_interface"].startswith("KUKA FRI torque mode: ")
    shown = analytic("export", "--help", cwd=tmp_path)
    assert "[default: (the run's)]" in " ".join(shown.stdout.split())


@pytest.mark.slow
def test_a_ur5e_run_exports_its_own_joints_and_torque_interface(tmp_path: Path) -> None:
    """A UR5e run (6 joints), tuned for real: its controller and its ros2_control file name the
    UR5e's joints, as ur_description does, and its torque interface; not the iiwa's."""
    quick = ("--trajectory", "fourier", "--duration", "0.5", "--pop", "4", "--generations", "2")
    made = analytic("start", "--robot", "ur5e", *quick, "--local", "--out", "run", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    done = analytic("export", "run", "--member", "1", "--format", "ros2_control", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    parameters = yaml.safe_load(done.stdout)["pd_effort_controller"]["ros__parameters"]
    assert parameters["joints"] == UR5E_JOINTS and list(parameters["gains"]) == UR5E_JOINTS
    comments = " ".join(line[2:] for line in done.stdout.splitlines() if line.startswith("#"))
    assert "ur5e's joint PD gains" in comments and "UR direct torque control" in comments
    assert "KUKA" not in comments and "A1" not in comments
    done = analytic("export", "run", "--member", "1", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    exported = yaml.safe_load(done.stdout)  # JSON is YAML
    assert exported["joints"] == UR5E_JOINTS and len(exported["kp"]) == 6
    assert exported["source"]["model"]["robot"] == "ur5e"
    assert exported["assumes"]["torque_interface"].startswith("UR direct torque control: ")
    assert exported["assumes"]["joints"].startswith(
        "shoulder_pan_joint..wrist_3_joint are ur5e's 6 joints"
    )
    refused = analytic("export", "run", "--member", "1", "--robot", "iiwa14", cwd=tmp_path)
    assert refused.returncode == 2
    assert refused.stderr == "analytic: error: --robot: 'run' is a run of ur5e, not of iiwa14\n"


@pytest.mark.slow
def test_validate_refuses_a_log_of_another_arm_than_its_twin(tmp_path: Path) -> None:
    """A UR5e's episode (6 joints, `worker episode --robot ur5e`) is not a held-out log of an
    iiwa twin: one line naming it, before any farm starts."""
    episode = tmp_path / "ur5e.mcap"
    one_second = ("--trajectory", "fourier", "--duration", "1", "--out", str(episode))
    made = subprocess.run(
        [sys.executable, "-m", "gainfarm.worker", "episode", "--robot", "ur5e", *one_second],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert made.returncode == 0, made.stderr
    twin = tmp_path / "twin.toml"
    twin.write_text('[plant]\nrobot = "iiwa14"\n')
    done = analytic("validate", str(twin), str(episode), "--local", "--out", "v", cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr == (
        f"analytic: error: {str(episode)!r} is an episode of ur5e, not of the twin's iiwa14\n"
    )
    assert not (tmp_path / "v").exists()


def test_validate_s_table_names_the_arm_s_joints(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The simulation error per joint, as `analytic validate` prints it: a row per joint of the
    twin's arm, by its name."""
    errors = [0.001 * (k + 1) for k in range(6)]
    side = {"q_rms": errors, "torque_rms": errors}
    report = {
        "episodes": [
            {"log": "a.mcap", **{n: {"f_acc": 0.002} for n in ("logged", "twin", "nominal")}}
        ],
        "summary": {"twin": side, "nominal": side, "q_ratio": 1.0},
    }
    monkeypatch.setenv("COLUMNS", "200")  # a row a line: rich reads the width from it
    validating._show(report, Path("v"), tuple(UR5E_JOINTS))
    shown = capsys.readouterr().out
    rows = [line.split("│")[1].strip() for line in shown.splitlines() if line.count("│") == 7]
    assert rows == UR5E_JOINTS
