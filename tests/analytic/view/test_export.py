"""The controller to use: the recommended member, the knee and the other picks on hand-made
fronts, the three formats parsed back, and a real run's knee exported and run again by `analytic
batch --gains` and `worker episode --gains`, reproducing the scores the run recorded for it."""

import json
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from gainfarm.analytic.tuning.picks import closest_index, dominating, knee_index, shortfall
from gainfarm.analytic.tuning.records import (
    Baseline,
    FrontMember,
    baseline_json,
    front_csv,
    read_front,
    sorted_front,
)
from gainfarm.analytic.view.export import (
    BadMember,
    BadRun,
    controller,
    pick,
    picks,
    point_groups,
    render,
)
from gainfarm.models import robot_of
from gainfarm.models.iiwa14 import RIGID_MJCF
from gainfarm.schemas.controller import FORMAT, UNITS, Assumptions, Controller, read_gains
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.robot import JOINT_NAMES, PlantSpec
from tests.analytic.samples import KD, KP
from tests.helpers import WEAK_GAINS, analytic, ends_with_closing_lines

WORKER = [sys.executable, "-c", "from gainfarm.worker.cli import main; main()"]
SHORT = ["--trajectory", "fourier", "--duration", "0.5"]


def front_of(*points: tuple[float, float], diverged: tuple[int, ...] = ()) -> list[FrontMember]:
    """Members at `points` (f_acc m, f_t), each with its own gains, in the order given."""
    return [
        FrontMember(
            kp=tuple(k * (1 + n / 10) for k in KP),
            kd=KD,
            objectives=(f_acc, f_t),
            diverged=n in diverged,
        )
        for n, (f_acc, f_t) in enumerate(points)
    ]


def named(front: list[FrontMember], baseline: Baseline | None = None) -> dict[str, int]:
    return {chosen.name: chosen.row for chosen in picks(front, baseline)}


def defaults_at(f_acc: float, f_t: float, diverged: bool = False) -> Baseline:
    return Baseline(DEFAULT_GAINS, objectives=(f_acc, f_t), diverged=diverged)


# --- the picks ---------------------------------------------------------------------------------


def test_the_knee_gives_up_neither_objective_and_weighs_factors_not_differences() -> None:
    # A chattering most-accurate member (f_t 1000) beside smooth ones: on linear scales every
    # smooth member would sit at f_t 0 and the knee would be row 2 (6 mm at f_t 2); on log
    # scales it is row 3, a tenth of the torque steps for 2 mm more error.
    front = front_of((0.005, 1000.0), (0.006, 2.0), (0.008, 0.2), (0.050, 0.1))
    assert named(front) == {"knee": 3, "accurate": 1, "smooth": 4}


def test_the_knee_is_defined_on_fronts_of_one_and_two_members() -> None:
    assert named(front_of((0.01, 0.5))) == {"knee": 1, "accurate": 1, "smooth": 1}
    # Two members are a tie (each is best in one objective): the lower row, the more accurate.
    assert named(front_of((0.01, 0.5), (0.02, 0.1))) == {"knee": 1, "accurate": 1, "smooth": 2}


def test_members_with_identical_scores_are_one_point_and_ties_go_to_the_lowest_row() -> None:
    front = front_of((0.005, 2.0), (0.01, 0.3), (0.01, 0.3), (0.01, 0.3), (0.05, 0.01))
    knee = pick(front, "knee")
    assert (knee.row, knee.sharing) == (2, 3)
    assert point_groups(front) == [(1, 1), (2, 3), (5, 1)]
    assert pick(front, "4").row == 4 and pick(front, "4").sharing == 3


def test_no_pick_is_a_diverged_member_unless_all_are() -> None:
    # The diverged member's penalty is not a measurement, however good it looks.
    front = front_of((0.001, 0.001), (0.01, 0.5), (0.02, 0.1), diverged=(0,))
    assert named(front) == {"knee": 2, "accurate": 2, "smooth": 3}
    everyone = front_of((5.0, 1e9), (6.0, 1e8), diverged=(0, 1))
    assert knee_index(everyone) == 0 and pick(everyone, "knee").member.diverged


def test_the_recommended_member_is_the_knee_among_those_that_dominate_the_default_gains() -> None:
    # The README's case: the front's knee (row 4, 18.6 mm) is 30 % less accurate than the
    # defaults (14.3 mm); rows 2 and 3 beat them on both objectives (row 2 matches their f_t and
    # is more accurate), and of those the knee's rule ranks row 3 best.
    front = front_of((0.005, 20.0), (0.0186, 0.2), (0.012, 2.0), (0.013, 1.9), (0.1, 0.1))
    defaults = defaults_at(0.0143, 2.0)
    assert named(front) == {"knee": 4, "accurate": 1, "smooth": 5}
    assert dominating(sorted_front(front), defaults) == [1, 2]
    assert named(front, defaults) == {"recommended": 3, "knee": 4, "accurate": 1, "smooth": 5}
    recommended = pick(front, "recommended", defaults)
    assert recommended.member.objectives == (0.013, 1.9) and recommended.name == "recommended"
    # Whenever the knee itself dominates the defaults, it is the one recommended.
    assert named(front, defaults_at(0.02, 0.3))["recommended"] == 4


def test_when_no_member_dominates_the_defaults_none_is_recommended_and_the_closest_is_named() -> (
    None
):
    # Row 1 is 10 times the defaults' f_t, row 2 twice their error, row 3 3 times their f_t.
    front = front_of((0.009, 10.0), (0.02, 0.5), (0.03, 0.1))
    defaults = defaults_at(0.01, 1.0)
    assert named(front, defaults) == {"closest": 2, "knee": 2, "accurate": 1, "smooth": 3}
    assert shortfall(front[1], defaults) == pytest.approx(np.log10(2.0))
    assert shortfall(front[0], defaults) == pytest.approx(1.0)
    # A member that is the defaults' own point falls short by nothing, yet does not dominate.
    assert closest_index(front_of((0.01, 1.0), (0.005, 1.5)), defaults) == 0
    assert "recommended" not in named(front_of((0.01, 1.0)), defaults)
    with pytest.raises(
        BadMember,
        match=r"no member of the front dominates the default gains .*"
        r"\(closest: row 2, report.md\); keep the default gains, run longer",
    ):
        pick(front, "recommended", defaults)
    with pytest.raises(BadMember, match=r"the run has no baseline\.json"):
        pick(front, "recommended")
    assert pick(front, "knee", defaults).row == 2  # the others are there still


def test_diverged_defaults_are_beaten_by_every_member_that_finished_and_by_no_diverged_one() -> (
    None
):
    front = front_of((0.001, 0.001), (0.01, 0.5), (0.02, 0.1), diverged=(0,))
    fell = defaults_at(2.0, 4e4, diverged=True)
    assert named(front, fell) == {"recommended": 2, "knee": 2, "accurate": 2, "smooth": 3}
    # A diverged member is never recommended, even beside defaults it would dominate.
    assert named(front, defaults_at(0.015, 1.0))["recommended"] == 2
    assert "recommended" not in named(front, defaults_at(0.005, 1.0))


@pytest.mark.parametrize(
    ("which", "says"),
    [
        (
            "middle",
            "expected recommended, knee, accurate, smooth or a row of front.csv (1-3), got "
            "'middle'",
        ),
        ("0", "row 0 is out of range: front.csv has 3 members (1-3)"),
        ("4", "row 4 is out of range"),
        ("-1", "row -1 is out of range"),
    ],
)
def test_a_member_the_front_does_not_have_is_refused(which: str, says: str) -> None:
    with pytest.raises(BadMember, match=says.replace("(", r"\(").replace(")", r"\)")):
        pick(front_of((0.01, 0.5), (0.02, 0.2), (0.03, 0.1)), which)


# --- the formats -------------------------------------------------------------------------------


@pytest.fixture
def hand_made(tmp_path: Path) -> Path:
    """A run directory as a run leaves it, written by hand: config, front, history, id."""
    directory = tmp_path / "run"
    directory.mkdir()
    (directory / "config.json").write_text('{"pop": 8, "generations": 3}')
    front = front_of((0.005, 1000.0), (0.006, 2.0), (0.008, 0.2), (0.050, 0.1))
    (directory / "front.csv").write_bytes(front_csv(front))
    (directory / "history.csv").write_text(
        "generation,evaluations,hypervolume,best_f_acc,best_f_t,wall_seconds\n"
        "1,8,0.5,0.01,0.1,1.0\n2,16,0.6,0.006,0.05,2.0\n3,24,0.7,0.005,0.05,3.0\n"
    )
    (directory / "run.json").write_text('{"run_id": "' + "ab" * 16 + '"}')
    return directory


def test_the_json_is_a_controller_with_gains_joints_units_scores_and_provenance(
    hand_made: Path,
) -> None:
    text = render(controller(hand_made, "knee"), "json")
    exported = Controller.model_validate_json(text)
    knee = read_front(hand_made / "front.csv")[2]
    assert exported.format == FORMAT and exported.joints == JOINT_NAMES
    assert (exported.kp, exported.kd) == (knee.kp, knee.kd)
    assert (
        exported.units
        == UNITS
        == {
            "kp": "N·m/rad",
            "kd": "N·m·s/rad",
            "f_acc": "m",
            "f_t": "(N·m)²",
        }
    )
    assert (exported.member.selected, exported.member.row) == ("knee", 3)
    assert (exported.member.f_acc, exported.member.f_t) == knee.objectives
    source = exported.source
    assert source.run_id == "ab" * 16 and source.plant == "realistic" and source.population == 8
    assert source.stopped == "3 generations"
    assert [t.kind for t in source.trajectories] == ["spiral"]
    assert read_gains(text) == [knee.gains]  # what --gains reads


def test_the_yaml_is_the_same_document(hand_made: Path) -> None:
    exported = controller(hand_made, "smooth")
    assert yaml.safe_load(render(exported, "yaml")) == json.loads(render(exported, "json"))


def test_the_ros2_control_file_runs_the_gains_on_the_models_joints(hand_made: Path) -> None:
    exported = controller(hand_made, "2")
    parameters = yaml.safe_load(render(exported, "ros2_control"))
    manager = parameters["controller_manager"]["ros__parameters"]
    assert manager["update_rate"] == 500  # the episodes' control rate
    assert manager["pd_effort_controller"]["type"] == (
        "joint_trajectory_controller/JointTrajectoryController"
    )
    assert manager["joint_state_broadcaster"]["type"] == (
        "joint_state_broadcaster/JointStateBroadcaster"
    )
    settings = parameters["pd_effort_controller"]["ros__parameters"]
    # The joints the model's motors drive, in their order: what the effort interfaces command.
    model = mujoco.MjModel.from_xml_path(str(RIGID_MJCF))
    driven = [model.joint(int(model.actuator_trnid[a, 0])).name for a in range(model.nu)]
    assert settings["joints"] == driven == list(JOINT_NAMES)
    assert settings["command_interfaces"] == ["effort"]
    assert settings["state_interfaces"] == ["position", "velocity"]
    for joint, kp, kd in zip(driven, exported.kp, exported.kd, strict=True):
        gains = settings["gains"][joint]
        assert gains == {"p": kp, "d": kd, "i": 0.0, "ff_velocity_scale": 0.0}
        # ROS 2 parameters are typed: an integer would be refused for a double.
        assert all(type(value) is float for value in gains.values())
    # A member chosen by its row says the row once; one chosen by name says both.
    comments = render(exported, "ros2_control").decode()
    assert "front.csv row 2.\n" in comments and "row 2: row 2" not in comments
    assert (
        "front.csv row 3: knee.\n" in render(controller(hand_made, "knee"), "ros2_control").decode()
    )


def test_the_files_say_what_running_the_gains_assumes(hand_made: Path) -> None:
    exported = controller(hand_made, "knee")
    assumes = Controller.model_validate_json(render(exported, "json")).assumes
    assert assumes is not None and assumes.update_rate_hz == 500
    assert assumes.joints.startswith("A1..A7 are iiwa14's 7 joints from base to flange")
    assert "map the names if your robot's description names them otherwise" in assumes.joints
    assert "KUKA FRI torque mode adds its gravity model" in assumes.gravity_compensation
    assert assumes.torque_interface is not None
    assert assumes.torque_interface.startswith("KUKA FRI torque mode: the robot adds")
    assert assumes.feedback.startswith("the motor-side joint angle")
    plain = Assumptions.of(PlantSpec(interface="torque", feedback="link"), robot_of("iiwa14"))
    assert plain.gravity_compensation.startswith("none: u is the whole motor torque")
    assert "KUKA FRI torque mode would add its gravity compensation" in plain.gravity_compensation
    assert plain.feedback == "the link-side joint angle and its velocity"
    # The ros2_control file says the same in its comments, each fact on lines of its own.
    comments = [
        line for line in render(exported, "ros2_control").decode().splitlines() if line[:1] == "#"
    ]
    said = " ".join(line[4:] for line in comments[comments.index(
        "# What it assumes (the JSON's `assumes` says the same):") + 1 :])  # fmt: skip
    for fact in (
        assumes.joints,
        assumes.torque_interface,
        assumes.gravity_compensation,
        assumes.feedback,
    ):
        assert fact in said
    assert "update rate: 500 Hz" in said


def test_the_default_export_is_the_recommended_member_beside_the_run_s_default_gains(
    hand_made: Path,
) -> None:
    # Rows: 5 mm at f_t 1000, 6 mm at 2, the knee 8 mm at 0.2, 50 mm at 0.1.
    (hand_made / "baseline.json").write_bytes(baseline_json(defaults_at(0.007, 3.0)))
    exported = controller(hand_made)
    assert (exported.member.selected, exported.member.row) == ("recommended", 2)
    assert "dominate the default gains" in exported.member.rule
    assert controller(hand_made, "knee").member.row == 3
    # A baseline.json of other gains (the defaults have changed since) compares nothing.
    other = Baseline(WEAK_GAINS, objectives=(0.007, 3.0), diverged=False)
    (hand_made / "baseline.json").write_bytes(baseline_json(other))
    with pytest.raises(BadMember, match=r"the run has no baseline\.json"):
        controller(hand_made)


def test_exporting_what_is_not_recommended_is_one_line_naming_the_closest_member(
    hand_made: Path,
) -> None:
    for baseline, says in [
        (
            None,
            "the run has no baseline.json of them (stopped before it scored them, or scored before "
            "they changed); name one: knee, accurate, smooth or a row of front.csv (1-4)",
        ),
        (
            defaults_at(0.004, 0.05),
            "no member of the front dominates the default gains (4.000 mm, f_t 0.05 (N·m)²), so "
            "none is recommended (closest: row 3, report.md); keep the default gains, run longer",
        ),
    ]:
        if baseline is not None:
            (hand_made / "baseline.json").write_bytes(baseline_json(baseline))
        ran = analytic("export", "run", "--out", "k.json", cwd=hand_made.parent)
        assert ran.returncode == 2 and ran.stdout == "", ran.stderr
        assert ran.stderr.startswith("analytic: error: --member: recommended (the default)")
        assert says in ran.stderr and len(ran.stderr.splitlines()) == 1
        assert not (hand_made.parent / "k.json").exists()


def test_a_directory_without_a_run_or_a_front_is_refused(tmp_path: Path) -> None:
    with pytest.raises(BadRun, match="holds no run"):
        controller(tmp_path)
    (tmp_path / "config.json").write_text("{}")
    with pytest.raises(BadRun, match="has no front yet"):
        controller(tmp_path)


# --- a real run, exported and run again --------------------------------------------------------


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny real run through the command line: MuJoCo episodes on a local farm. Nominal and
    on the paper's f_t: the tests run its members' episodes again and compare each with the
    scores the run recorded, which a robust run's are not (the worst over its plants)."""
    here = tmp_path_factory.mktemp("export")
    ran = analytic(
        "start",
        "--pop",
        "4",
        "--generations",
        "2",
        *SHORT,
        "--plants",
        "0",
        "--torque-measure",
        "raw",
        "--local",
        "--out",
        "run",
        cwd=here,
    )
    assert ran.returncode == 0, ran.stderr
    ends_with_closing_lines(ran.stderr.splitlines(), here / "run")
    return here / "run"


def worker(*arguments: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*WORKER, *arguments], cwd=cwd, capture_output=True, text=True, timeout=300
    )


@pytest.mark.slow
def test_the_exported_knee_runs_again_to_the_scores_its_run_recorded(run_dir: Path) -> None:
    here = run_dir.parent
    exported = analytic("export", "run", "--member", "knee", "--out", "knee.json", cwd=here)
    assert exported.returncode == 0 and exported.stdout == "", exported.stderr
    knee = json.loads((here / "knee.json").read_text())
    member = read_front(run_dir / "front.csv")[knee["member"]["row"] - 1]
    assert (tuple(knee["kp"]), tuple(knee["kd"])) == (member.kp, member.kd)
    assert (
        f"| knee of the whole front | {knee['member']['row']} |"
        in (run_dir / "report.md").read_text()
    )

    batch = analytic(
        "batch", "--local", "--gains", "knee.json", *SHORT, "--run-dir", "b", "--json", cwd=here
    )
    assert batch.returncode == 0, batch.stderr
    [result] = [json.loads(line) for line in batch.stdout.splitlines()]
    assert (result["f_acc"], result["f_t"]) == member.objectives  # deterministic

    episode = worker(
        "episode", "--gains", "knee.json", *SHORT, "--out", "knee.mcap", "--json", cwd=here
    )
    assert episode.returncode == 0, episode.stderr
    scores = json.loads(episode.stdout)
    assert (scores["f_acc"], scores["f_t"]) == member.objectives


@pytest.mark.slow
def test_batch_runs_a_whole_front_csv_again(run_dir: Path) -> None:
    here = run_dir.parent
    front = read_front(run_dir / "front.csv")
    batch = analytic(
        "batch",
        "--local",
        "--gains",
        "run/front.csv",
        *SHORT,
        "--run-dir",
        "all",
        "--json",
        cwd=here,
    )
    assert batch.returncode == 0, batch.stderr
    evaluations = sorted(
        (json.loads(line) for line in batch.stdout.splitlines()), key=lambda e: e["job_id"]
    )
    assert [(e["f_acc"], e["f_t"]) for e in evaluations] == [m.objectives for m in front]


@pytest.mark.slow
def test_every_format_is_written_whole_to_a_file_or_to_standard_output(run_dir: Path) -> None:
    here = run_dir.parent
    for fmt in ("json", "yaml", "ros2_control"):
        to_file = analytic(
            "export", "run", "--member", "smooth", "--format", fmt, "--out", fmt, cwd=here
        )
        to_stdout = analytic("export", "run", "--member", "smooth", "--format", fmt, cwd=here)
        assert to_file.returncode == to_stdout.returncode == 0, to_file.stderr
        assert (here / fmt).read_text() == to_stdout.stdout
        assert yaml.safe_load(to_stdout.stdout)  # JSON is YAML too: all three parse


@pytest.mark.slow
def test_a_diverged_episode_says_why_its_mean_error_exceeds_its_largest(tmp_path: Path) -> None:
    weak = tmp_path / "weak.json"
    weak.write_text(json.dumps([WEAK_GAINS.model_dump()]))
    batch = analytic(
        "batch",
        "--local",
        "--gains",
        "weak.json",
        "--trajectory",
        "fourier",
        "--duration",
        "1",
        "--plant",
        "plain",
        "--run-dir",
        "b",
        cwd=tmp_path,
    )
    assert batch.returncode == 0, batch.stderr
    assert "diverged" in batch.stdout
    assert "so f_acc and f_t are a penalty, not a measurement" in " ".join(batch.stdout.split())


@pytest.mark.parametrize(
    ("arguments", "says"),
    [
        (["nothere"], "'nothere' holds no run (no config.json)"),
        (["empty"], "'empty' has no front yet"),
        (["run", "--member", "middle"], "--member: expected recommended, knee, accurate, smooth"),
        (["run", "--member", "999"], "--member: row 999 is out of range: front.csv has"),
        (["run", "--format", "xml"], "Invalid value for '--format': 'xml' is not one of"),
        (
            ["run", "--member", "knee", "--out", "missing/k.json"],
            "--out: directory 'missing' does not exist",
        ),
        (
            ["run", "--member", "knee", "--out", "taken"],
            "--out: cannot write 'taken': Is a directory",
        ),
    ],
)
def test_bad_export_options_are_one_line_and_write_nothing(
    run_dir: Path, tmp_path: Path, arguments: list[str], says: str
) -> None:
    (tmp_path / "run").symlink_to(run_dir)
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "config.json").write_text("{}")
    (tmp_path / "taken").mkdir()
    before = sorted(path.name for path in tmp_path.rglob("*"))
    ran = analytic("export", *arguments, cwd=tmp_path)
    assert ran.returncode == 2, ran.stderr
    assert ran.stderr.startswith(f"analytic: error: {says}"), ran.stderr
    assert len(ran.stderr.splitlines()) == 1 and ran.stdout == ""
    assert sorted(path.name for path in tmp_path.rglob("*")) == before
