"""From a hidden arm's logs to a twin, and back: `analytic calibrate` and `analytic validate`.

A hidden arm is a plant file whose numbers are drawn outside the shipped uncertainty ranges
(bench/calibration.py's `hidden_arm`: rotors ten to twelve times heavier, stiffness, friction
and its shape some three times off either way, a delay of three ticks, heavier or lighter links
and a tool); it stands in for a real robot through `worker episode --plant HIDDEN`, and
calibration sees only its logs.
"""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.calibration import hidden_arm, write_plant
from gainfarm.analytic.calibration.logs import Recording, read_recording
from gainfarm.analytic.tuning.plants import ranges, ranges_of, variants
from gainfarm.cli.app import CliError
from gainfarm.cli.values import plant_file
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.plant_file import BadPlantFile, read_plant_file
from gainfarm.schemas.robot import PlantSpec
from tests.helpers import analytic, crafted_log, write_log

N = 7
EXCITATIONS, HELD_OUT = 6, (6, 7)  # the held-out ones: the next seeds excite writes
DURATION = "8"


def record(directory: Path, hidden: Path, seeds: tuple[int, ...], gains: Path) -> list[Path]:
    """`worker episode` on the hidden arm, as a robot-side user plays each excitation: real
    processes, two at a time (the cores)."""
    paths = [directory / f"excitation-{seed:03d}.mcap" for seed in seeds]
    pending = []
    for seed, path in zip(seeds, paths, strict=True):
        command = [
            sys.executable, "-m", "gainfarm.worker", "episode", "--plant", str(hidden),
            "--trajectory", "fourier", "--trajectory-seed", str(seed), "--duration", DURATION,
            "--gains", str(gains), "--out", str(path), "--json",
        ]  # fmt: skip
        pending.append(subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE))
        if len(pending) == 2:
            _wait(pending)
    _wait(pending)
    return paths


def _wait(pending: list[subprocess.Popen]) -> None:
    for process in pending:
        _, err = process.communicate(timeout=120)
        assert process.returncode == 0, err.decode()
    pending.clear()


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A hidden arm, its recorded excitations and held-out episodes, and the twin calibrated on
    the excitations."""
    directory = tmp_path_factory.mktemp("calibration")
    arm = hidden_arm(2026)
    hidden = write_plant(directory / "hidden.toml", arm)
    excite = directory / "excite"
    done = analytic(
        "excite", "--out", str(excite), "--count", str(EXCITATIONS), "--duration", DURATION,
        cwd=directory,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    # The robot side plays each excitation with the controller excite chose.
    seeds = tuple(
        json.loads(path.read_text())["trajectory"]["seed"]
        for path in sorted(excite.glob("excitation-*.json"))
    )
    assert len(seeds) == EXCITATIONS
    gains = excite / "controller.json"
    logs = record(directory, hidden, seeds, gains)
    held_out = record(directory, hidden, HELD_OUT, gains)
    twin = directory / "twin.toml"
    done = analytic("calibrate", *map(str, logs), "--out", str(twin), "--json", cwd=directory)
    assert done.returncode == 0, done.stderr
    return {
        "arm": arm,
        "twin": twin,
        "fit": json.loads(done.stdout),
        "held_out": held_out,
        "logs": logs,
        "directory": directory,
    }


def test_the_twin_recovers_the_hidden_arm(calibrated: dict) -> None:
    arm: PlantSpec = calibrated["arm"]
    twin = read_plant_file(calibrated["twin"].read_bytes())
    plant = twin.plant
    assert arm.friction is not None and plant.friction is not None
    assert plant.delay == arm.delay  # exactly
    smoothing = plant.friction.smoothing / arm.friction.smoothing
    assert twin.calibration["smoothing"]["told"] and abs(smoothing - 1) < 0.1, smoothing
    told = {name: np.array(twin.calibration[name]["told"]) for name in twin.calibration if name in (
        "rotor_inertia", "coulomb", "viscous", "stiffness")}  # fmt: skip
    for name, recovered, true in (
        ("rotor_inertia", plant.rotor_inertia, arm.rotor_inertia),
        ("coulomb", plant.friction.coulomb, arm.friction.coulomb),
        ("viscous", plant.friction.viscous, arm.friction.viscous),
        ("stiffness", plant.stiffness, arm.stiffness),
    ):
        ratio = np.asarray(recovered) / np.asarray(true)
        # Within 10 % wherever the logs told it; the rest untold, and said so.
        assert np.all(np.abs(ratio[told[name]] - 1) < 0.1), (name, ratio)
        assert told[name].all() or twin.calibration[name]["why"], name
    # Every joint's rotor and Coulomb friction is told; the viscous part only where a heavy
    # rotor does not drown it (this arm's A5 and A6; bench/calibration.py counts them).
    assert told["rotor_inertia"].all() and told["coulomb"].all() and told["viscous"].sum() >= 2
    # A7 turns the flange alone: its torque is the sensor's noise, so its stiffness is untold,
    # said, and left at the nominal.
    stiffness = twin.calibration["stiffness"]
    assert stiffness["told"] == [True] * 6 + [False]
    assert "cannot tell stiffness" in stiffness["why"]
    assert plant.stiffness[6] == PlantSpec().stiffness[6]
    # The controller's settings are the nominal's, never the log's.
    assert (plant.interface, plant.feedback, plant.inertials) == ("fri", "motor", "menagerie")
    assert [log["name"] for log in twin.calibration["logs"]] == [p.name for p in calibrated["logs"]]


def test_the_twins_uncertainty_is_what_robust_tuning_draws(calibrated: dict) -> None:
    twin = read_plant_file(calibrated["twin"].read_bytes())
    table = {name: entry for name, entry in twin.uncertainty.items()}
    delay = calibrated["arm"].delay
    assert table["delay"]["low"] == table["delay"]["high"] == delay
    rotor = table["rotor_inertia"]
    assert rotor["per_joint"] and all(
        0.9 < low < 1 < high < 1.1 for low, high in zip(rotor["low"], rotor["high"], strict=True)
    )
    stiffness = table["stiffness"]
    assert stiffness["low"][6] == 0.5 and stiffness["high"][6] == 2.0  # A7's: the shipped range
    drawn = variants(twin.plant, 16, seed=1, uncertainty=ranges_of(twin.uncertainty))
    rotor_ratios = np.array([p.rotor_inertia for p in drawn]) / np.asarray(twin.plant.rotor_inertia)
    assert rotor_ratios.min() >= min(rotor["low"]) and rotor_ratios.max() <= max(rotor["high"])
    assert {p.delay for p in drawn} == {delay}
    shipped = variants(twin.plant, 16, seed=1, uncertainty=ranges())
    assert {p.delay for p in shipped} != {delay}  # the shipped ranges would not have known it


def test_robust_tuning_on_the_twin_draws_from_its_uncertainty(calibrated: dict) -> None:
    from gainfarm.analytic.commands.work.common import plants_from

    twin_path = str(calibrated["twin"])
    twin = read_plant_file(calibrated["twin"].read_bytes()).plant
    # `analytic start --plant TWIN --plants K` (and its held-out check): the twin's ranges.
    for held_out in (False, True):
        drawn = plants_from(8, None, twin, seed=4, held_out=held_out, plant=twin_path)
        assert {p.delay for p in drawn} == {twin.delay}
        rotor = np.array([p.rotor_inertia for p in drawn]) / np.asarray(twin.rotor_inertia)
        assert rotor.min() > 0.9 and rotor.max() < 1.1
    # A named plant keeps the shipped ranges.
    shipped = plants_from(8, None, twin, seed=4, plant="realistic")
    assert len({p.delay for p in shipped}) > 1


@pytest.fixture(scope="module")
def validated(calibrated: dict) -> dict:
    """`analytic validate` of the held-out episodes' logs: its JSON output."""
    directory = calibrated["directory"]
    out = directory / "validation"
    done = analytic(
        "validate", str(calibrated["twin"]), *map(str, calibrated["held_out"]),
        "--out", str(out), "--local", "--workers", "1", "--json", cwd=directory,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_a_twin_calibrated_again_keeps_its_own_ranges_where_the_logs_tell_nothing(
    calibrated: dict, tmp_path: Path
) -> None:
    import tomllib

    import tomli_w

    table = tomllib.loads(calibrated["twin"].read_text())
    table["uncertainty"]["encoder_noise"].update(low=0.9, high=1.1, why="measured on our arm")
    prior = tmp_path / "prior.toml"
    prior.write_text(tomli_w.dumps(table))
    again = tmp_path / "again.toml"
    logs = [str(p) for p in calibrated["logs"]]
    done = analytic("calibrate", *logs, "--plant", str(prior), "--out", str(again), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    twin = read_plant_file(again.read_bytes())
    assert twin.uncertainty["encoder_noise"]["why"] == "measured on our arm"
    # The same logs, the same numbers (the smoothing's search starts from the prior's own).
    first = read_plant_file(calibrated["twin"].read_bytes()).plant
    assert twin.plant.delay == first.delay
    assert np.allclose(twin.plant.rotor_inertia, first.rotor_inertia, rtol=0.01)


def test_validate_measures_the_gap_the_twin_closes(calibrated: dict, validated: dict) -> None:
    out = calibrated["directory"] / "validation"
    report = validated
    assert report == json.loads((out / "validation.json").read_text())
    assert report["summary"]["q_ratio"] <= 0.2
    twin_q = np.array(report["summary"]["twin"]["q_rms"])
    nominal_q = np.array(report["summary"]["nominal"]["q_rms"])
    assert np.all(twin_q < nominal_q)
    for episode in report["episodes"]:
        logged = episode["logged"]["f_acc"]
        assert abs(episode["twin"]["f_acc"] - logged) / logged < 0.1
        # The nominal plant is the wrong arm: its prediction is off by far more.
        assert abs(episode["nominal"]["f_acc"] - logged) / logged > 0.3


def test_a_worker_runs_an_episode_on_the_twin(calibrated: dict, tmp_path: Path) -> None:
    command = [
        sys.executable, "-m", "gainfarm.worker", "episode", "--plant", str(calibrated["twin"]),
        "--trajectory", "fourier", "--duration", "1", "--out", str(tmp_path / "ep.mcap"),
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr

    # The twin's calibrated payload is the load the robot is told as the file runs (told: the
    # plant holds what the file's does, the robot's gravity model carries the payload).
    twin = read_plant_file(calibrated["twin"].read_bytes())
    ran = read_episode(tmp_path / "ep.mcap").metadata.spec.plant
    assert ran == twin.told().plant
    assert ran.payload == 0.0 and ran.load is not None
    assert ran.load.mass == pytest.approx(twin.plant.payload)


def test_bad_input_is_one_line_and_writes_nothing(calibrated: dict, tmp_path: Path) -> None:
    logs = [str(p) for p in calibrated["logs"][:2]]
    other = tmp_path / "xarm7.toml"
    other.write_text('[plant]\nrobot = "xarm7"\n')
    not_a_log = tmp_path / "notes.mcap"
    not_a_log.write_text("hello")
    out = tmp_path / "twin.toml"
    cases = {
        ("--plant", "no plug-in named 'xarm7'"): [*logs, "--plant", str(other), "--out", str(out)],
        ("notes.mcap", "not"): [str(not_a_log), "--out", str(out)],
        ("missing.mcap", "no such file"): [str(tmp_path / "missing.mcap"), "--out", str(out)],
        ("--out", "does not exist"): [*logs, "--out", str(tmp_path / "no" / "twin.toml")],
        ("--plant", "neither"): [*logs, "--plant", "gazebo", "--out", str(out)],
    }
    for (where, what), arguments in cases.items():
        done = analytic("calibrate", *arguments, cwd=tmp_path)
        assert done.returncode != 0
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and where in lines[0] and what in lines[0], done.stderr
        assert "Traceback" not in done.stderr
    assert not out.exists()
    for arguments, says in (
        ([str(other), *logs], "TWIN: "),
        ([str(calibrated["twin"]), *logs, "--nominal", str(other)], "--nominal: "),
    ):
        done = analytic("validate", *arguments, "--out", str(tmp_path / "v"), cwd=tmp_path)
        assert done.returncode != 0 and len(done.stderr.splitlines()) == 1, done.stderr
        assert says in done.stderr and "no plug-in named 'xarm7'" in done.stderr, done.stderr
    assert not (tmp_path / "v").exists()


def test_what_is_neither_a_log_nor_a_bag_is_one_line_naming_it(tmp_path: Path) -> None:
    """Refused before anything is fitted, each in one line: a directory that holds no bag, a
    binary file, and an episode log cut short (an MCAP file, so both readers are asked)."""
    (tmp_path / "logs").mkdir()
    (tmp_path / "noise.bin").write_bytes(bytes(range(256)))
    write_log(crafted_log(), tmp_path / "whole.mcap")
    (tmp_path / "cut.mcap").write_bytes((tmp_path / "whole.mcap").read_bytes()[:-40])
    for given, says in (
        ("logs", "'logs' is a directory but no ROS 2 bag (no metadata.yaml in it)"),
        ("noise.bin", "'noise.bin': not an MCAP file (no MCAP magic at its start)"),
        (
            "cut.mcap",
            "'cut.mcap': neither an episode log (truncated MCAP file (no MCAP magic at its end)) "
            "nor a ROS 2 bag rosbags can read (File end magic is invalid.)",
        ),
    ):
        done = analytic("calibrate", given, "--out", "twin.toml", cwd=tmp_path)
        assert done.returncode == 2, done.stderr
        assert done.stderr == f"analytic: error: {says}\n"
    assert not (tmp_path / "twin.toml").exists()


def test_a_plant_file_from_another_robot_is_refused_in_one_line(tmp_path: Path) -> None:
    # The contract reads it (a robot is a plug-in); a command line here has no such robot.
    assert read_plant_file(b'[plant]\nrobot = "xarm7"\n').plant.robot == "xarm7"
    (tmp_path / "xarm7.toml").write_text('[plant]\nrobot = "xarm7"\n')
    with pytest.raises(CliError, match=r"xarm7\.toml': gainfarm\.robots: no plug-in named 'xarm7'"):
        plant_file(str(tmp_path / "xarm7.toml"))
    with pytest.raises(BadPlantFile, match=r"plant\.robot: must match"):
        read_plant_file(b'[plant]\nrobot = "UR5e"\n')
    with pytest.raises(BadPlantFile, match="not TOML"):
        read_plant_file(b"[plant\n")
    with pytest.raises(BadPlantFile, match=r"plant\.delay"):
        read_plant_file(b"[plant]\ndelay = -1\n")
    assert read_plant_file(b"[plant]\n").plant == PlantSpec()


# --- a robot's ROS 2 bags ------------------------------------------------------------------------


def write_bag(
    path: Path,
    recording: Recording,
    *,
    every_ns: int = 2_000_000,
    repeat: int = 1,
    keep: slice | np.ndarray | None = None,
    effort: bool = True,
    commands: str = "/joint_commands",
) -> Path:
    """`recording` as a robot would log it: JointState on /joint_states, /joint_commands (the
    torque sent) and /motor_states, stamped `every_ns` apart (each message `repeat` times, a
    faster logger's), MCAP storage; `keep` picks the ticks written (a gap)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    state = store.types["sensor_msgs/msg/JointState"]
    header, stamp = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    names = [f"A{i}" for i in range(1, 8)]
    ticks = np.arange(recording.ticks)[keep if keep is not None else slice(None)]
    empty = np.zeros(0)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        topics = {
            topic: writer.add_connection(topic, "sensor_msgs/msg/JointState", typestore=store)
            for topic in ("/joint_states", commands, "/motor_states")
        }
        for tick in ticks:
            for copy in range(repeat):
                ns = int(tick) * every_ns + copy * every_ns // repeat
                head = header(stamp=stamp(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="")
                messages = {
                    "/joint_states": (recording.q, recording.qd, recording.tau if effort else None),
                    commands: (np.zeros_like(recording.q), None, recording.command),
                    "/motor_states": (recording.theta, recording.theta_d, None),
                }
                for topic, (position, velocity, torque) in messages.items():
                    message = state(
                        header=head,
                        name=names,
                        position=position[tick],
                        velocity=velocity[tick] if velocity is not None else empty,
                        effort=torque[tick] if torque is not None else empty,
                    )
                    writer.write(
                        topics[topic], ns, store.serialize_cdr(message, message.__msgtype__)
                    )
    return path


def test_a_robots_bags_calibrate_the_same_twin(calibrated: dict, tmp_path: Path) -> None:
    bags = [
        write_bag(tmp_path / f"bag-{index}", read_recording(log))
        for index, log in enumerate(calibrated["logs"])
    ]
    twin = tmp_path / "twin.toml"
    done = analytic("calibrate", *map(str, bags), "--out", str(twin), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    # The same numbers as the episode logs hold, read through rosbags: the same twin.
    assert (
        read_plant_file(twin.read_bytes()).plant
        == read_plant_file(calibrated["twin"].read_bytes()).plant
    )


def test_a_faster_bag_is_taken_at_the_plants_rate(calibrated: dict, tmp_path: Path) -> None:
    recording = read_recording(calibrated["logs"][0])
    slow = read_recording(write_bag(tmp_path / "500", recording))
    fast = read_recording(write_bag(tmp_path / "1k", recording, repeat=2))
    for name in ("q", "qd", "tau", "command", "theta", "theta_d"):
        assert np.array_equal(getattr(slow, name), getattr(fast, name)), name
    assert np.array_equal(slow.q, recording.q) and slow.fed_back == "motor"


def test_a_bag_calibration_cannot_use_is_one_line(calibrated: dict, tmp_path: Path) -> None:
    recording = read_recording(calibrated["logs"][0])
    keep = np.r_[0:1000, 1010 : recording.ticks]
    bags = {
        "has no effort": write_bag(tmp_path / "no-torque", recording, effort=False),
        "is at 250 Hz": write_bag(tmp_path / "slow", recording, every_ns=4_000_000),
        "has a gap of 22 ms at t = 1.998 s": write_bag(tmp_path / "gap", recording, keep=keep),
        "no /joint_commands topic": write_bag(tmp_path / "topic", recording, commands="/cmd"),
    }
    jumped = dataclasses.replace(recording, q=recording.q.copy())
    jumped.q[2000:, 3] += 0.2
    bags["rad in A4 at t = 4.000 s, more than 3 times its speed limit"] = write_bag(
        tmp_path / "jump", jumped
    )
    for what, bag in bags.items():
        done = analytic("calibrate", str(bag), "--out", str(tmp_path / "twin.toml"), cwd=tmp_path)
        assert done.returncode != 0
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and what in lines[0] and str(bag) in lines[0], done.stderr
    assert not (tmp_path / "twin.toml").exists()
    # The topic another robot uses is named by its option.
    done = analytic(
        "calibrate", str(bags["no /joint_commands topic"]), "--commands", "/cmd",
        "--out", str(tmp_path / "twin.toml"), cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr


def test_validate_pairs_a_robots_bags_with_what_they_played(
    calibrated: dict, validated: dict
) -> None:
    directory = calibrated["directory"]
    held = directory / "excite-held"
    first, count = HELD_OUT[0], str(len(HELD_OUT))
    done = analytic(
        "excite", "--out", str(held), "--seed", str(first), "--count", count,
        "--duration", DURATION, cwd=directory,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    bags = [
        write_bag(directory / f"held-bag-{index}", read_recording(log))
        for index, log in enumerate(calibrated["held_out"])
    ]
    # Given in the other order: each bag is paired with the reference it follows.
    excitations = sorted(held.glob("excitation-*.json"), reverse=True)
    played = [arg for path in excitations for arg in ("--played", str(path))]
    out = directory / "validation-bags"
    done = analytic(
        "validate", str(calibrated["twin"]), *map(str, bags), *played,
        "--out", str(out), "--local", "--workers", "1", "--json", cwd=directory,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["summary"]["q_ratio"] <= 0.2
    for bag, log in zip(report["episodes"], validated["episodes"], strict=True):
        # The same episodes, read from the bag: the same replays, the same logged accuracy
        # (the flange from the measured angles, not the simulator's: micrometres apart).
        assert bag["twin"] == log["twin"] and bag["nominal"] == log["nominal"]
        assert abs(bag["logged"]["f_acc"] / log["logged"]["f_acc"] - 1) < 0.01
    # A bag with nothing said of what it played, or with what it did not: one line each.
    for arguments, says in (
        ([], "names no controller: say what was played (--played"),
        (["--played", str(directory / "excite" / "excitation-00.json")],
         "follows none of --played's references"),
    ):  # fmt: skip
        done = analytic(
            "validate", str(calibrated["twin"]), str(bags[0]), *arguments, cwd=directory
        )
        assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
        assert says in done.stderr, done.stderr


def test_batch_and_experiment_take_the_twin(calibrated: dict, tmp_path: Path) -> None:
    twin = str(calibrated["twin"])
    done = analytic(
        "batch", "--local", "--workers", "1", "--plant", twin, "--trajectory", "fourier",
        "--duration", "1", "--run-dir", str(tmp_path / "batch"), "--json", cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    (episode,) = [json.loads(line) for line in done.stdout.splitlines()]
    plant = read_episode(tmp_path / "batch" / episode["episode"]).metadata.spec.plant
    # As the twin file runs: its calibrated payload the load the robot is told (PlantFile.told).
    assert plant == read_plant_file(calibrated["twin"].read_bytes()).told().plant
    # An experiment reads it as it parses its options: a bad one is refused before anything runs.
    bad = tmp_path / "bad.toml"
    bad.write_text("[plant]\ndelay = 99\n")
    done = analytic("experiment", "speed", "--plant", str(bad), "--out", "x", cwd=tmp_path)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
    assert "--plant" in done.stderr and "plant.delay" in done.stderr, done.stderr
    assert not (tmp_path / "x").exists()
