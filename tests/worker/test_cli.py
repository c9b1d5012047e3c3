"""The command lines, run as a user runs them: real subprocesses, real files."""

import json
import subprocess
import sys

import pytest
from mcap_ros2.reader import read_ros2_messages

from gainfarm.models import robot_of
from gainfarm.models.ur5e import JOINT_NAMES as UR5E_JOINT_NAMES
from gainfarm.schemas.mcap_episode import read_episode

WORKER = [sys.executable, "-c", "from gainfarm.worker.cli import main; main()"]
ANALYTIC = [sys.executable, "-c", "from gainfarm.analytic.cli import main; main()"]


def run(command: list[str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*command, *args], capture_output=True, text=True, timeout=120)


@pytest.mark.slow
def test_episode_writes_a_log_that_analytic_scores_identically(tmp_path):
    out = tmp_path / "ep.mcap"
    simulated = run(
        WORKER, "episode", "--trajectory", "pyramid", "--duration", "3", "--out", str(out), "--json"
    )
    assert simulated.returncode == 0, simulated.stderr
    worker_scores = json.loads(simulated.stdout)
    assert {"f_acc", "f_t", "diverged"} <= worker_scores.keys()
    evaluated = run(ANALYTIC, "evaluate", str(out), "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    assert json.loads(evaluated.stdout) == worker_scores


def test_human_readable_scores(tmp_path):
    out = tmp_path / "ep.mcap"
    result = run(
        WORKER,
        "episode",
        "--trajectory",
        "fourier",
        "--duration",
        "0.5",
        "--out",
        str(out),
        "--joints",
        "rigid",
    )
    assert result.returncode == 0, result.stderr
    assert "f_acc" in result.stdout and "mm" in result.stdout
    # The log's path on a line of its own, to be copied: no trailing spaces on any line.
    assert result.stdout.splitlines()[0] == str(out)
    assert [line for line in result.stdout.splitlines() if line != line.rstrip()] == []


SEVEN = "1,1,1,1,1,1,1"

UR5E_JOINTS = list(UR5E_JOINT_NAMES)


@pytest.mark.slow
def test_a_six_joint_episode_on_the_ur5e_logs_its_joints(tmp_path):
    """`worker episode --robot ur5e`: its default spiral at its workspace centre, its default
    gains, its realistic plant; the log, read by an independent ROS 2 decoder, names its six
    joints, and the analytic side scores it as the worker did."""
    out = tmp_path / "ur5e.mcap"
    simulated = run(WORKER, "episode", "--robot", "ur5e", "--out", str(out), "--json")
    assert simulated.returncode == 0, simulated.stderr
    worker_scores = json.loads(simulated.stdout)
    assert worker_scores["diverged"] is False and worker_scores["ticks"] == 2501
    names, urdf, frames = {}, "", set()
    for message in read_ros2_messages(str(out)):
        if message.channel.topic not in names:
            names[message.channel.topic] = list(getattr(message.ros_msg, "name", []))
        if message.channel.topic == "/robot_description":
            urdf = message.ros_msg.data
        if message.channel.topic == "/tf":
            frames |= {t.child_frame_id for t in message.ros_msg.transforms}
    assert names["/joint_states"] == names["/joint_commands"] == UR5E_JOINTS
    # The log draws the UR5e for ROS tools: its own URDF and every link's frame on /tf.
    assert urdf.startswith("<?xml") and all(f'joint name="{j}"' in urdf for j in UR5E_JOINTS)
    assert "flange" in frames and "wrist_3_link" in frames
    log = read_episode(out)
    assert log.q.shape == (2501, 6) and list(log.metadata.joint_names) == UR5E_JOINTS
    assert log.metadata.spec.plant.robot == "ur5e"
    assert log.metadata.spec.trajectory.center == robot_of("ur5e").workspace.center
    assert log.metadata.spec.gains == robot_of("ur5e").default_gains
    evaluated = run(ANALYTIC, "evaluate", str(out), "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    assert json.loads(evaluated.stdout) == worker_scores


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["--kp", SEVEN], "--kp: 7 gains for ur5e's 6 joints"),
        (["--robot", "iiwa14", "--kd", "1,1,1,1,1,1"], "--kd: 6 gains for iiwa14's 7 joints"),
        (["--payload", "6"], "--payload: 6 kg is beyond ur5e's rated 5 kg"),
    ],
)
def test_gains_and_loads_are_counted_against_the_robots_joints(tmp_path, args, line):
    result = run(WORKER, "episode", "--robot", "ur5e", "--out", str(tmp_path / "e.mcap"), *args)
    assert result.returncode == 2
    assert result.stderr == f"worker: error: {line}\n"
    assert list(tmp_path.iterdir()) == []


def test_a_robot_this_installation_lacks_is_one_line(tmp_path):
    result = run(WORKER, "episode", "--robot", "nosucharm", "--out", str(tmp_path / "e.mcap"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.count("\n") <= 2 and "'nosucharm' is no robot here" in result.stderr


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--kp", "1,2,3"], "--kp: 3 gains for iiwa14's 7 joints"),
        (["--center", "1,2"], "expected 3 numbers"),
        (["--size", "-0.1"], "size"),
        (["--kd", "1,1,1,1,1,1,nan"], "finite and non-negative"),
        (["--kp", "1,1,1,1,1,1,-3"], "finite and non-negative"),
        (["--kp", "one,two"], "comma-separated numbers"),
        (["--trajectory", "circle"], "circle"),
        (["--duration", "0"], "duration"),
        (["--duration", "1e9"], "duration"),
        (["--joints", "soft"], "soft"),
        (["--plant", "perfect"], "perfect"),
        (["--trajectory", "pyramid", "--duration", "0.5"], "shortest feasible duration"),
        (["--trajectory", "spiral", "--kp", SEVEN, "--trajectory-seed", "x"], "trajectory-seed"),
    ],
)
@pytest.mark.slow
def test_bad_input_is_one_clear_line_and_no_file(tmp_path, args, says):
    out = tmp_path / "ep.mcap"
    result = run(WORKER, "episode", "--out", str(out), *args)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("worker: error:")
    assert says in result.stderr
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_unwritable_destination_is_a_clear_error(tmp_path):
    result = run(WORKER, "episode", "--out", str(tmp_path / "missing" / "ep.mcap"))
    assert result.returncode == 2 and "does not exist" in result.stderr


def test_unreachable_path_is_a_clear_error(tmp_path):
    out = tmp_path / "ep.mcap"
    result = run(WORKER, "episode", "--center", "2,0,0.4", "--duration", "0.5", "--out", str(out))
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1, result.stderr
    assert result.stderr.startswith(
        "worker: error: --center/--size: the path is unreachable at 0 % of the path: the pose at "
    ), result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["--duration", "0"], "--duration: must be at least 0.1, got 0"),
        (["--duration", "200"], "--duration: must be at most 120, got 200"),
        (
            ["--gravity-compensation"],
            "--gravity-compensation: the realistic plant already adds the robot's own gravity "
            "compensation (KUKA FRI torque mode); with --plant plain or --plant ideal the PD's "
            "torque is the whole motor torque, and this flag adds it",
        ),
        (
            ["--trajectory", "spiral", "--duration", "1"],
            "--duration: the 1 s spiral is too fast for iiwa14: A7 would need 2.55x its "
            "speed limit; the shortest feasible duration is 2.6 s",
        ),
    ],
)
def test_bad_options_are_one_plain_line_naming_the_option(tmp_path, args, line):
    result = run(WORKER, "episode", "--out", str(tmp_path / "ep.mcap"), *args)
    assert result.returncode == 2
    assert result.stderr == f"worker: error: {line}\n"
    assert list(tmp_path.iterdir()) == []


GAINS = {"kp": [2000, 2000, 1200, 1200, 400, 200, 100], "kd": [20, 20, 15, 15, 4, 2, 1]}


@pytest.mark.parametrize(
    ("content", "args", "says"),
    [
        (json.dumps(GAINS), ["--kp", SEVEN], "--gains and --kp exclude each other"),
        (json.dumps(GAINS), ["--kp", SEVEN, "--kd", SEVEN], "--gains and --kp and --kd exclude"),
        (json.dumps([GAINS, GAINS]), [], "holds 2 candidates and an episode runs one"),
        ("kp1,kp2\n1,2\n", [], "a run's front.csv, not a controller: `analytic export RUN"),
        (json.dumps({**GAINS, "kp": [1, 2, 3]}), [], "kp: 3 gains given, 7 needed (A1..A7)"),
        (
            json.dumps({**GAINS, "kd": [1, 1, 1, -1, 1, 1, 1]}),
            [],
            "kd of A4: -1 is negative (gains are at least 0)",
        ),
        (json.dumps({"format": "gainfarm-controller/9", **GAINS}), [], "format 'gainfarm-contr"),
        ("{", [], "not JSON (Expecting property name enclosed in double quotes at line 1"),
    ],
)
@pytest.mark.slow
def test_a_bad_gains_file_is_one_line_naming_the_option_and_no_file(tmp_path, content, args, says):
    gains = tmp_path / "gains.json"
    gains.write_text(content)
    out = tmp_path / "out"
    out.mkdir()
    result = run(WORKER, "episode", "--gains", str(gains), "--out", str(out / "ep.mcap"), *args)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("worker: error: --gains")
    assert says in result.stderr
    assert list(out.iterdir()) == []


@pytest.mark.slow
def test_a_diverged_episode_says_why_its_mean_error_exceeds_its_largest(tmp_path):
    out = tmp_path / "ep.mcap"
    weak = ["--kp", "5,5,5,5,5,5,5", "--kd", SEVEN, "--trajectory", "fourier", "--duration", "1"]
    weak += ["--plant", "plain"]  # without the robot's gravity compensation, the arm falls
    result = run(WORKER, "episode", *weak, "--out", str(out))
    assert result.returncode == 0, result.stderr
    said = " ".join(result.stdout.split())
    assert "diverged │ yes" in said
    assert "so f_acc and f_t are a penalty, not a measurement" in said
    evaluated = run(ANALYTIC, "evaluate", str(out))
    assert "so f_acc and f_t are a penalty, not a measurement" in " ".join(evaluated.stdout.split())


def _controller_file(tmp_path, trajectory: dict) -> str:
    """An exported controller tuned on `trajectory` (TrajectorySpec fields) on the realistic
    plant, as `analytic export` writes it."""
    from gainfarm.schemas.gains import DEFAULT_GAINS
    from gainfarm.schemas.trajectory import TrajectorySpec
    from tests.schemas.test_controller import exported

    document = exported(DEFAULT_GAINS)
    document["source"]["trajectories"] = [TrajectorySpec(**trajectory).model_dump(mode="json")]
    path = tmp_path / "use.json"
    path.write_text(json.dumps(document))
    return str(path)


def test_a_controller_run_off_what_it_was_tuned_on_says_so_and_as_tuned_runs_it_as_tuned(
    tmp_path,
):
    controller = _controller_file(tmp_path, {"kind": "fourier", "duration": 1.0, "seed": 2})
    other = run(WORKER, "episode", "--gains", controller, "--trajectory", "fourier",
                "--duration", "1", "--out", str(tmp_path / "a.mcap"), "--json")  # fmt: skip
    assert other.returncode == 0, other.stderr
    assert other.stderr == (
        f"worker: warning: --gains {controller!r}: tuned on the 1 s fourier (seed 2), run on the "
        "1 s fourier (seed 0) (--as-tuned runs it as tuned)\n"
    )
    for options, says in (
        (["--plant", "plain"], "tuned on the realistic plant, run on the plain plant"),
        (
            ["--joints", "rigid"],
            "tuned on the realistic plant with flexible joints, run on the realistic plant with "
            "rigid joints",
        ),
        (
            ["--size", "0.1"],
            "tuned on the 1 s fourier (seed 2, size 0.08 m), run on the 1 s "
            "fourier (seed 2, size 0.1 m)",
        ),
        (
            ["--center", "0.5,0,0.4", "--plant", "ideal"],
            "tuned on the 1 s fourier (seed 2, centre 0.55,0,0.35 m), run on the 1 s fourier "
            "(seed 2, centre 0.5,0,0.4 m); tuned on the realistic plant, run on the ideal plant",
        ),
    ):
        off = run(WORKER, "episode", "--gains", controller, "--trajectory", "fourier",
                  "--duration", "1", "--trajectory-seed", "2", *options,
                  "--out", str(tmp_path / "a.mcap"), "--json")  # fmt: skip
        assert off.returncode == 0, off.stderr
        assert off.stderr == (
            f"worker: warning: --gains {controller!r}: {says} (--as-tuned runs it as tuned)\n"
        )
    saturating = str(tmp_path / "sat.json")
    (tmp_path / "sat.json").write_text(json.dumps({**GAINS, "kp": [1e30, *GAINS["kp"][1:]]}))
    tuned = run(WORKER, "episode", "--gains", controller, "--as-tuned",
                "--out", str(tmp_path / "b.mcap"), "--json")  # fmt: skip
    assert tuned.returncode == 0 and tuned.stderr == "", tuned.stderr
    from gainfarm.schemas.mcap_episode import read_episode

    spec = read_episode(tmp_path / "b.mcap").metadata.spec
    assert (spec.trajectory.kind, spec.trajectory.duration, spec.trajectory.seed) == (
        "fourier",
        1.0,
        2,
    )
    for arguments, says in (
        (["--gains", controller, "--as-tuned", "--duration", "2"], "--as-tuned and --duration"),
        (["--as-tuned"], "--as-tuned needs --gains with a controller"),
        (["--kp", "1e30,1,1,1,1,1,1"], "--kp: kp of A1 is 1e+30, which saturates its motor"),
        (
            ["--gains", saturating],
            f"--gains: {saturating!r}: kp of A1 is 1e+30, which saturates its motor on one encoder "
            "count: every tick would saturate",
        ),
    ):
        refused = run(WORKER, "episode", *arguments, "--out", str(tmp_path / "c.mcap"))
        assert refused.returncode == 2 and refused.stderr.count("\n") == 1, refused.stderr
        assert says in refused.stderr, refused.stderr
        assert not (tmp_path / "c.mcap").exists()


@pytest.mark.parametrize(
    ("gains", "options", "says"),
    [
        (
            None,
            ["--kd", "20,20,1e-6,15,4,2,1"],
            "--kd: kd of A3 is 1e-06 N·m·s/rad, 1/1,500,000 of the search space's lowest "
            "(1.5 N·m·s/rad: 0.1× the default 15)",
        ),
        (  # 1000× the default Kp: far outside the search, yet no motor saturates on one count
            {"kp": [k * 1000 for k in GAINS["kp"]], "kd": GAINS["kd"]},
            [],
            "--gains 'far.json': kp of A1 is 2e+06 N·m/rad, 333× the search space's highest "
            "(6000 N·m/rad: 3× the default 2000)",
        ),
    ],
)
def test_gains_far_outside_the_search_space_run_with_one_line_naming_the_option(
    tmp_path, monkeypatch, gains, options, says
):
    monkeypatch.chdir(tmp_path)  # the file named as given, relative
    if gains is not None:
        (tmp_path / "far.json").write_text(json.dumps(gains))
        options = ["--gains", "far.json"]
    ran = run(WORKER, "episode", *options, "--trajectory", "fourier", "--duration", "0.2",
              "--out", "ep.mcap", "--json")  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    assert ran.stderr == (
        f"worker: warning: {says}: far outside what the farm searches (a slip of units or of an "
        "exponent?)\n"
    )
    assert json.loads(ran.stdout)["ticks"] == 101  # the episode ran, whole
    assert (tmp_path / "ep.mcap").is_file()


@pytest.mark.slow
def test_an_exported_yaml_controller_runs_as_its_json_does(tmp_path):
    """`analytic export --format yaml` writes the same document as the JSON: `worker episode
    --gains` and `analytic batch --gains` take it, and score it as they score the JSON."""
    tiny = ["--pop", "4", "--generations", "1", "--trajectory", "fourier", "--duration", "0.5"]
    # The nominal problem on the paper's f_t: the member's recorded scores are one episode's.
    tiny += ["--plants", "0", "--torque-measure", "raw"]
    started = run(ANALYTIC, "start", "--local", *tiny, "--out", str(tmp_path / "run"))
    assert started.returncode == 0, started.stderr
    scores = {}
    for form in ("json", "yaml"):
        file = tmp_path / f"c.{form}"
        exported = run(ANALYTIC, "export", str(tmp_path / "run"), "--member", "1",
                       "--format", form, "--out", str(file))  # fmt: skip
        assert exported.returncode == 0, exported.stderr
        ran = run(WORKER, "episode", "--gains", str(file), "--as-tuned",
                  "--out", str(tmp_path / f"{form}.mcap"), "--json")  # fmt: skip
        assert ran.returncode == 0 and ran.stderr == "", ran.stderr
        scores[form] = json.loads(ran.stdout)
        batch = run(ANALYTIC, "batch", "--local", "--workers", "1", "--gains", str(file),
                    "--trajectory", "fourier", "--duration", "0.5", "--json",
                    "--run-dir", str(tmp_path / f"batch-{form}"))  # fmt: skip
        assert batch.returncode == 0, batch.stderr
        (result,) = [json.loads(line) for line in batch.stdout.splitlines()]
        assert result["f_acc"] == scores[form]["f_acc"]
        assert result["f_t"] == scores[form]["f_t"]
    assert {**scores["yaml"], "log": ""} == {**scores["json"], "log": ""}
    member = json.loads((tmp_path / "c.json").read_text())["member"]
    assert (scores["yaml"]["f_acc"], scores["yaml"]["f_t"]) == (member["f_acc"], member["f_t"])
