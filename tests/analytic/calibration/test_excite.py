"""`analytic excite`, run as a user runs it: real subprocesses, real files read back by ROS 2
readers and replayed by `worker episode`; and every refusal leaves nothing behind."""

import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from gainfarm.analytic.calibration import excitation as ex
from gainfarm.analytic.tuning.plants import variants
from gainfarm.models import robot_of
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.robot import (
    ACCELERATION_LIMITS,
    JOINT_NAMES,
    POSITION_LIMITS,
    SPEED_LIMITS,
    PlantSpec,
)
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.reference import Reference, reference_for

ANALYTIC = [sys.executable, "-c", "from gainfarm.analytic.cli import main; main()"]
WORKER = [sys.executable, "-c", "from gainfarm.worker.cli import main; main()"]
DURATION, COUNT, SEED = 3.0, 2, 5
TICKS = round(DURATION / 0.002) + 1


def run(command: list[str], *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*command, *args], capture_output=True, text=True, timeout=120, cwd=cwd)


@pytest.fixture(scope="module")
def excite(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """`analytic excite` into a new directory: the directory and what it printed."""
    where = tmp_path_factory.mktemp("excite")
    out = where / "EXCITE"
    args = ["--duration", f"{DURATION:g}", "--count", str(COUNT), "--seed", str(SEED)]
    result = run(ANALYTIC, "excite", "--out", str(out), *args, cwd=where)
    assert result.returncode == 0, result.stderr
    return out, result.stdout


def documents(out: Path) -> list[dict]:
    return [json.loads((out / f"excitation-{n:02d}.json").read_text()) for n in range(COUNT)]


def test_it_writes_the_references_the_gains_and_a_readme(excite):
    out, stdout = excite
    names = {f"excitation-{n:02d}.{suffix}" for n in range(COUNT) for suffix in ("json", "mcap")}
    assert {path.name for path in out.iterdir()} == names | {"controller.json", "README.md"}
    assert [path.name for path in out.parent.iterdir()] == ["EXCITE"]  # no staging left over
    lines = stdout.splitlines()
    assert len(lines) == 2 and lines[0].startswith(f"{out}: {COUNT} excitations of 3 s")
    assert "seeds 5 to 6" in lines[0] and "least damping +0.0" in lines[1]
    controller = json.loads((out / "controller.json").read_text())
    assert controller == ex.GAINS.model_dump(mode="json")
    # The factory gains scaled together: softer, the same shape.
    assert np.allclose(np.array(controller["kp"]) / DEFAULT_GAINS.kp, ex.GAIN_SCALE)
    assert np.allclose(np.array(controller["kd"]) / DEFAULT_GAINS.kd, ex.GAIN_SCALE)
    readme = (out / "README.md").read_text()
    for needed in (
        "/joint_states",
        "/joint_commands",
        "/motor_states",
        "FRI torque mode",
        "analytic calibrate LOG... --out TWIN",
        "analytic excite --duration 3 --count 2 --seed 5",
        "Kp 600, 600, 360",
    ):
        assert needed in readme
    assert max(len(line) for line in readme.splitlines()) <= ex.WIDTH


def test_each_json_is_its_fourier_reference_within_the_limits(excite):
    out, _ = excite
    for n, document in enumerate(documents(out)):
        trajectory = TrajectorySpec(kind="fourier", duration=DURATION, seed=SEED + n)
        assert document["trajectory"] == trajectory.model_dump(mode="json")
        assert document["control_period"] == 0.002
        assert document["joint_names"] == list(JOINT_NAMES)
        assert document["gains"] == ex.GAINS.model_dump(mode="json")
        reference = reference_for(trajectory)
        q, qd, qdd = (np.array(document[k]) for k in ("positions", "velocities", "accelerations"))
        assert q.shape == qd.shape == qdd.shape == (TICKS, 7)
        # Exactly the worker's reference: JSON round-trips every float64.
        assert np.array_equal(document["t"], reference.t)
        assert np.array_equal(q, reference.q) and np.array_equal(qd, reference.qd)
        assert np.array_equal(qdd, reference.qdd)
        assert (np.abs(q) <= POSITION_LIMITS).all() and (np.abs(qd) <= SPEED_LIMITS).all()
        assert (np.abs(qdd) <= ACCELERATION_LIMITS).all()
        assert np.ptp(q, axis=0).min() >= ex.MIN_SPAN
        assert np.abs(qd[[0, -1]]).max() < 1e-9  # rest to rest


def test_each_mcap_is_one_joint_trajectory_that_rosbags_reads_back(excite):
    from rosbags.highlevel import AnyReader

    out, _ = excite
    for n, document in enumerate(documents(out)):
        with AnyReader([out / f"excitation-{n:02d}.mcap"]) as reader:
            (connection,) = reader.connections
            assert connection.topic == "/joint_trajectory"
            assert connection.msgtype == "trajectory_msgs/msg/JointTrajectory"
            messages = list(reader.messages())
            assert len(messages) == 1
            message = reader.deserialize(messages[0][2], connection.msgtype)
        assert message.joint_names == list(JOINT_NAMES)
        assert len(message.points) == TICKS
        for field, key in (
            ("positions", "positions"),
            ("velocities", "velocities"),
            ("accelerations", "accelerations"),
        ):
            values = np.array([getattr(point, field) for point in message.points])
            assert np.array_equal(values, document[key])
        nanoseconds = [
            p.time_from_start.sec * 10**9 + p.time_from_start.nanosec for p in message.points
        ]
        assert nanoseconds == [tick * 2_000_000 for tick in range(TICKS)]
        assert np.allclose(np.array(nanoseconds) / 1e9, document["t"], rtol=0, atol=1e-12)


def test_each_mcap_reads_back_with_the_mcap_library_and_its_ros2_decoder(excite):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out, _ = excite
    for n, document in enumerate(documents(out)):
        with open(out / f"excitation-{n:02d}.mcap", "rb") as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            assert reader.get_header().profile == "ros2"
            (metadata,) = list(reader.iter_metadata())
            decoded = list(reader.iter_decoded_messages())
        assert json.loads(metadata.metadata["trajectory"]) == document["trajectory"]
        ((schema, channel, _, message),) = decoded
        assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
        positions = np.array([point.positions for point in message.points])
        assert np.array_equal(positions, document["positions"])


def test_worker_episode_plays_it_with_the_controller_file(excite, tmp_path):
    """What the user plays on the arm is what the simulation plays: the same reference, tick for
    tick, under the same gains."""
    from gainfarm.schemas.mcap_episode import read_episode

    out, _ = excite
    n = 1
    document = documents(out)[n]
    log = tmp_path / "ep.mcap"
    result = run(
        WORKER,
        "episode",
        "--gains",
        str(out / "controller.json"),
        "--trajectory",
        "fourier",
        "--trajectory-seed",
        str(SEED + n),
        "--duration",
        f"{DURATION:g}",
        "--out",
        str(log),
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    episode = read_episode(log)
    assert np.array_equal(episode.q_des, document["positions"])
    assert episode.metadata.spec.gains == ex.GAINS
    assert not episode.metadata.diverged
    assert episode.metadata.damping is not None and episode.metadata.damping > 0


def test_an_empty_directory_is_filled(tmp_path):
    out = tmp_path / "empty"
    out.mkdir()
    result = run(
        ANALYTIC, "excite", "--out", str(out), "--count", "1", "--duration", "2", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    assert {path.name for path in out.iterdir()} == {
        "excitation-00.json",
        "excitation-00.mcap",
        "controller.json",
        "README.md",
    }
    assert [path.name for path in tmp_path.iterdir()] == ["empty"]


# The ranges of a plant with rotors a hundredth of the nominal: the gains' closed loop is
# unstable on every such plant (least damping −0.25 to −0.55 on the references here).
TINY_ROTORS = """\
[rotor_inertia]
field = "rotor_inertia"
per_joint = true
draw = "log"
low = 0.01
high = 0.01
why = "a test: rotors far lighter than any arm's"
"""


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--count", "0"], "'--count': 0 is not in the range 1<=x<=100"),
        (["--count", "101"], "'--count'"),
        (["--seed", "-1"], "'--seed'"),
        (["--duration", "0.05"], "--duration: 0.05 s is outside 0.1 to 120 s"),
        (["--duration", "nan"], "--duration: nan s is outside"),
        (["--duration", "1", "--count", "1"], "--duration: 1 s is too short to excite A"),
        # Refused at the third, after two passed and were staged: their files go too.
        (["--duration", "1.2", "--count", "3"], "excitation-02 (seed 2) moves it"),
        (["--uncertainty", "tiny.toml", "--count", "2", "--duration", "2"], "--uncertainty: "),
        (["--uncertainty", "missing.toml"], "--uncertainty: cannot read"),
        (
            ["--uncertainty", "empty.toml"],
            "analytic: error: --uncertainty: 'empty.toml' holds no ranges (a table per "
            "parameter, as in the shipped models/uncertainty.toml)\n",
        ),
    ],
)
def test_bad_input_is_one_line_naming_the_option_and_nothing_is_written(tmp_path, args, says):
    (tmp_path / "tiny.toml").write_text(TINY_ROTORS)
    (tmp_path / "empty.toml").write_text("")
    result = run(ANALYTIC, "excite", "--out", "EXCITE", *args, cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.startswith("analytic: error: ") and result.stderr.count("\n") == 1
    assert says in result.stderr
    assert sorted(path.name for path in tmp_path.iterdir()) == ["empty.toml", "tiny.toml"]


def test_unstable_gains_are_refused_naming_the_excitation_the_variant_and_its_damping(tmp_path):
    (tmp_path / "tiny.toml").write_text(TINY_ROTORS)
    args = ["--uncertainty", "tiny.toml", "--count", "2", "--duration", "2", "--seed", "3"]
    result = run(ANALYTIC, "excite", "--out", "EXCITE", *args, cwd=tmp_path)
    assert result.returncode == 2
    stated = re.search(
        r"--uncertainty: the gains are unstable along excitation-00 \(seed 3\) on plant variant 1 "
        r"of 8 drawn from 'tiny.toml' \(least damping (-[\d.]+)\)",
        result.stderr,
    )
    assert stated and float(stated.group(1)) < -0.1, result.stderr


@pytest.mark.parametrize("existing", ["a non-empty directory", "a file"], ids=["directory", "file"])
def test_an_existing_out_is_refused_and_left_alone(tmp_path, existing):
    out = tmp_path / "EXCITE"
    if existing == "a file":
        out.write_text("mine")
    else:
        out.mkdir()
        (out / "mine.txt").write_text("mine")
    result = run(ANALYTIC, "excite", "--out", str(out), cwd=tmp_path)
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert "--out: " in result.stderr and "already exists and is not an empty directory" in (
        result.stderr
    )
    assert [path.name for path in tmp_path.iterdir()] == ["EXCITE"]
    if existing == "a file":
        assert out.read_text() == "mine"
    else:
        assert [path.name for path in out.iterdir()] == ["mine.txt"]


# --- the checks themselves ----------------------------------------------------------------------


def test_the_factory_gains_would_be_refused_where_the_excitation_gains_pass():
    """Why controller.json holds softer gains than the factory's: on seed 0's variants of the
    shipped ranges the factory gains' loop is unstable, the excitation gains' is not."""
    trajectory = ex.trajectory(DURATION, 0)
    reference = reference_for(trajectory)
    plants = variants(PlantSpec(), ex.VARIANTS, 0)
    with pytest.raises(ex.Unsafe) as refused:
        ex.check_stable(0, DEFAULT_GAINS, trajectory, reference, plants, "the shipped ranges")
    assert refused.value.option == "--uncertainty"
    assert "plant variant 2 of 8 drawn from the shipped ranges (least damping -0.00" in str(
        refused.value
    )
    assert ex.check_stable(0, ex.GAINS, trajectory, reference, plants, "the shipped ranges") > 0


def _altered(reference: Reference, **arrays: np.ndarray) -> Reference:
    fields = {k: getattr(reference, k) for k in ("t", "ee", "q", "qd", "qdd")}
    return Reference(**(fields | arrays))


@pytest.mark.parametrize(
    ("column", "joint", "value", "says"),
    [
        ("q", 3, 2.2, "A4 reaches 2.200 rad, beyond its joint range of ±2.094 rad"),
        ("qd", 1, -1.6, "A2 reaches 1.600 rad/s, beyond its speed limit of ±1.484 rad/s"),
        ("qdd", 6, 20.0, "A7 reaches 20.000 rad/s², beyond its acceleration limit of ±15.720"),
        ("qd", 2, float("nan"), "A3 reaches nan rad/s"),
    ],
)
def test_a_reference_beyond_a_published_limit_is_refused_naming_the_joint(
    column, joint, value, says
):
    """The fourier kind scales itself into the limits; the check stands behind it."""
    trajectory = ex.trajectory(DURATION, 0)
    reference = reference_for(trajectory)
    ex.check_limits(0, trajectory, reference)  # the real one passes
    values = np.array(getattr(reference, column))
    values[len(values) // 2, joint] = value
    with pytest.raises(ex.Unsafe) as refused:
        ex.check_limits(0, trajectory, _altered(reference, **{column: values}))
    assert refused.value.option == "--seed" and says in str(refused.value)


def test_a_reference_that_does_not_start_at_rest_is_refused():
    trajectory = ex.trajectory(DURATION, 0)
    reference = reference_for(trajectory)
    qd = np.array(reference.qd)
    qd[0, 2] = 0.01
    with pytest.raises(ex.Unsafe, match="does not start at rest"):
        ex.check_limits(0, trajectory, _altered(reference, qd=qd))


# --- another arm: the UR5e (6 joints) --------------------------------------------------------


def ur5e_ranges(path: Path) -> Path:
    """The UR5e's shipped ranges with its rotors at least half the nominal (as the iiwa 14's
    ranges have them), written to `path`. Its shipped factor of four lighter makes plants whose
    linearised loop is unstable at any gains (×0.01 as at ×1: the wrists' light rotors), which
    excite rightly refuses; a user's arm's ranges are the user's to give (--uncertainty)."""
    table = tomllib.loads(robot_of("ur5e").uncertainty.read_text())
    table["rotor_inertia"]["low"] = 0.5
    path.write_text(tomli_w.dumps(table))
    return path


def test_the_ur5e_is_excited_within_its_own_limits_with_its_own_gains(tmp_path):
    from rosbags.highlevel import AnyReader

    ur5e = robot_of("ur5e")
    out = tmp_path / "EXCITE"
    args = ["--duration", f"{DURATION:g}", "--count", "1", "--seed", str(SEED)]
    args += ["--uncertainty", str(ur5e_ranges(tmp_path / "ranges.toml"))]
    result = run(ANALYTIC, "excite", "--robot", "ur5e", "--out", str(out), *args, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "within ur5e's limits" in result.stdout
    (document,) = [json.loads((out / "excitation-00.json").read_text())]
    assert document["robot"] == "ur5e"
    assert document["joint_names"] == list(ur5e.joint_names)
    reference = reference_for(TrajectorySpec(kind="fourier", duration=DURATION, seed=SEED), "ur5e")
    q, qd, qdd = (np.array(document[k]) for k in ("positions", "velocities", "accelerations"))
    assert q.shape == (TICKS, 6) and np.array_equal(q, reference.q)
    assert (np.abs(q) <= ur5e.limits.position).all()
    assert (np.abs(qd) <= ur5e.limits.speed).all()
    assert (np.abs(qdd) <= ur5e.limits.acceleration).all()
    assert np.ptp(q, axis=0).min() >= ex.MIN_SPAN
    # Its own factory gains, scaled as the iiwa's are.
    controller = json.loads((out / "controller.json").read_text())
    assert np.allclose(np.array(controller["kp"]) / ur5e.default_gains.kp, ex.GAIN_SCALE)
    assert len(controller["kd"]) == 6
    with AnyReader([out / "excitation-00.mcap"]) as reader:
        (connection,) = reader.connections
        ((_, _, raw),) = list(reader.messages())
        message = reader.deserialize(raw, connection.msgtype)
    assert message.joint_names == list(ur5e.joint_names)
    readme = (out / "README.md").read_text()
    assert "Universal Robots UR5e" in readme and "shoulder_pan_joint" in readme
    assert "analytic calibrate LOG... --robot ur5e --out TWIN" in readme
    assert ur5e.torque_interface.name in readme
    assert "A1..A7" not in readme and "iiwa" not in readme


def test_a_reference_beyond_the_ur5es_limits_is_refused_naming_its_joint():
    trajectory = TrajectorySpec(kind="fourier", duration=DURATION, seed=0)
    reference = reference_for(trajectory, "ur5e")
    ex.check_limits(0, trajectory, reference, "ur5e")  # the real one passes
    qd = np.array(reference.qd)
    qd[len(qd) // 2, 0] = 1.01 * robot_of("ur5e").limits.speed[0]
    with pytest.raises(ex.Unsafe, match="leaves ur5e's published limits: shoulder_pan_joint "):
        ex.check_limits(0, trajectory, _altered(reference, qd=qd), "ur5e")
    # The iiwa's reference is no UR5e's: seven joints for six.
    with pytest.raises(ex.Unsafe, match="moves 7 joints, not ur5e's"):
        ex.check_limits(0, trajectory, reference_for(trajectory), "ur5e")
