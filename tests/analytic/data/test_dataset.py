"""The dataset: what goes in is exactly what the episodes logged, under ids that never collide,
split by trajectory, with units; real runs on a real local farm, real MCAP logs."""

import contextlib
import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from gainfarm.analytic.cli import main
from gainfarm.analytic.compose import new_study_name
from gainfarm.analytic.data import dataset as dataset_module
from gainfarm.analytic.data.dataset import (
    RERUN_DIR,
    SPLITS,
    BadRerun,
    BadSplit,
    DuplicateEpisodes,
    NoEpisodes,
    RerunFarm,
    assign_splits,
    build,
    select,
    split_counts,
    trajectory_id,
)
from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import RUN_JSON, read_identity, read_run
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.analytic.view.export import controller
from gainfarm.cli import interrupts
from gainfarm.models import robot_of
from gainfarm.schemas import TrajectorySpec
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.robot import JOINT_NAMES, PLAIN_PLANT, PlantSpec
from gainfarm.worker.episode import motor_torque
from tests.helpers import write_log

SPIRAL = TrajectorySpec(duration=3.0)
# The limits these tiny runs (a few random candidates) were written under, before the lag and the
# damping's bound: under today's defaults the twin's four candidates all break one (two chatter,
# two lag 93 and 237 mrad on its plain interface) and the first run's front is another, so the
# tests of what a dataset does with a front would have none, or a different one, to read.
LIMITS_OF_THE_FIXTURES = Limits(speed=1.5, lag=None, min_damping=None)
CONFIG = RunConfig(
    pop=4,
    seed=3,
    trajectories=(
        SPIRAL,
        TrajectorySpec(kind="random", duration=3.0),
        TrajectorySpec(kind="pyramid", duration=3.0),
    ),
    generations=2,
    limits=LIMITS_OF_THE_FIXTURES,
)
# Another run, in another directory of the same name, sharing the spiral; on a plain torque
# interface, so that a dataset mixes both interfaces.
TWIN = RunConfig(
    pop=4,
    seed=5,
    trajectories=(SPIRAL,),
    generations=1,
    plant=PLAIN_PLANT,
    limits=LIMITS_OF_THE_FIXTURES,
)
RERUN = [
    # Seed 0: the pyramid unturned (a turned one at this centre asks A4 for more than its range).
    TrajectorySpec(kind="pyramid", duration=3.0, seed=0, center=(0.5, 0.1, 0.4)),
    TrajectorySpec(kind="fourier", duration=3.0, seed=2),
]
# A UR5e's run (6 joints), on three short excitations: one trajectory a part.
UR5E_RUN = RunConfig(
    pop=4,
    seed=3,
    trajectories=tuple(TrajectorySpec(kind="fourier", duration=2.0, seed=k) for k in range(3)),
    generations=1,
    plant=PlantSpec(robot="ur5e"),
    limits=LIMITS_OF_THE_FIXTURES,
)
ANALYTIC = [sys.executable, "-m", "gainfarm.analytic", "dataset"]
SIGNALS = ("q", "qd", "tau", "u", "theta", "theta_d", "q_des", "qd_des")
ARRAYS = ("t", *SIGNALS, "ee", "ee_des")


@pytest.fixture(scope="module")
def endpoint() -> Iterator[str]:
    with local_farm(workers=2) as endpoint:
        yield endpoint


def tune(directory: Path, config: RunConfig, endpoint: str) -> Path:
    run = TuningRun.create(directory, config)
    with run, FarmClient([endpoint], new_study_name(directory), directory) as farm:
        run.run(farm)
    return directory


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory, endpoint: str) -> Path:
    return tune(tmp_path_factory.mktemp("runs") / "generic", CONFIG, endpoint)


@pytest.fixture(scope="module")
def twin_dir(tmp_path_factory: pytest.TempPathFactory, endpoint: str) -> Path:
    return tune(tmp_path_factory.mktemp("elsewhere") / "generic", TWIN, endpoint)


@pytest.fixture(scope="module")
def ur5e_dir(tmp_path_factory: pytest.TempPathFactory, endpoint: str) -> Path:
    return tune(tmp_path_factory.mktemp("ur5e") / "ur5e", UR5E_RUN, endpoint)


def farm_at(endpoint: str) -> RerunFarm:
    """The rerun's farm: the module's local one, a new study per rerun."""

    @contextlib.contextmanager
    def farm(directory: Path) -> Iterator[Evaluator]:
        with FarmClient([endpoint], new_study_name(directory), directory) as client:
            yield client

    return farm


def tables(dataset: Path) -> tuple[dict, dict, dict]:
    return tuple(  # type: ignore[return-value]
        pq.read_table(dataset / f"{name}.parquet").to_pydict()
        for name in ("ticks", "episodes", "trajectories")
    )


def assert_ticks_are_the_logs(dataset: Path) -> int:
    """Every MCAP log of the dataset, value for value in ticks.parquet, with its qdd computed
    within the episode, its trajectory_id and its split agreeing across the three tables.
    Returns how many logs."""
    ticks, episodes, trajectories = tables(dataset)
    logs = sorted((dataset / "episodes").glob("*.mcap"))
    assert len(logs) == len(episodes["episode_id"]) == len(set(episodes["episode_id"]))
    assert sum(episodes["ticks"]) == len(ticks["t"])
    episode_ids = np.array(ticks["episode_id"])
    split_of = dict(zip(trajectories["trajectory_id"], trajectories["split"], strict=True))
    for path in logs:
        log = read_episode(path)
        joints = robot_of(log.metadata.spec.plant).joint_names  # the columns' names
        rows = episode_ids == path.stem
        assert rows.sum() == log.ticks
        np.testing.assert_array_equal(np.array(ticks["t"])[rows], log.t)
        qdd = np.array([ticks[f"qdd_{joint}"] for joint in joints]).T[rows]
        np.testing.assert_array_equal(qdd[:-1], np.diff(log.qd, axis=0) / 0.002)
        assert np.isnan(qdd[-1]).all()  # the last tick: no next one, never the next episode's
        for index, joint in enumerate(joints):
            for signal in SIGNALS:
                values = np.array(ticks[f"{signal}_{joint}"])[rows]
                np.testing.assert_array_equal(values, getattr(log, signal)[:, index])
        # The motors' whole torque: behind FRI the command and the robot's gravity model (the
        # loop's own numbers: tests/worker/test_episode.py), on a torque interface the command.
        u_motor = np.array([ticks[f"u_motor_{joint}"] for joint in joints]).T[rows]
        np.testing.assert_array_equal(u_motor, motor_torque(log))
        fri = log.metadata.spec.plant.interface == "fri"
        # A2 (the UR5e's shoulder lift) holds the arm up.
        assert fri == (np.abs(u_motor - log.u)[:, 1].min() > 10), fri
        for index, axis in enumerate("xyz"):
            np.testing.assert_array_equal(np.array(ticks[f"ee_{axis}"])[rows], log.ee[:, index])
            np.testing.assert_array_equal(
                np.array(ticks[f"ee_des_{axis}"])[rows], log.ee_des[:, index]
            )
        tid = trajectory_id(log.metadata.spec.trajectory)
        assert set(np.array(ticks["trajectory_id"])[rows]) == {tid}
        assert set(np.array(ticks["split"])[rows]) == {split_of[tid]}
        row = episodes["episode_id"].index(path.stem)
        assert episodes["trajectory_id"][row] == tid and episodes["split"][row] == split_of[tid]
        assert episodes[f"kp_{joints[0]}"][row] == log.metadata.spec.gains.kp[0]
        assert episodes["ticks"][row] == log.ticks
    return len(logs)


@pytest.mark.slow
def test_the_tick_table_is_the_episodes_tick_by_tick(run_dir: Path, tmp_path: Path) -> None:
    counts = build([run_dir], tmp_path / "dataset")
    assert assert_ticks_are_the_logs(tmp_path / "dataset") == counts["episodes"] >= 3
    ticks, episodes, trajectories = tables(tmp_path / "dataset")
    assert counts["ticks"] == len(ticks["t"])
    assert {"spiral", "random", "pyramid"} == set(episodes["trajectory"])
    assert set(episodes["source"]) == {"tuning"} and set(episodes["run"]) == {"generic"}
    run_id = read_identity(run_dir / RUN_JSON).run_id
    assert set(episodes["run_id"]) == {run_id}
    assert all(name.startswith(f"{run_id[:8]}-g") for name in episodes["episode_id"])
    assert len(trajectories["trajectory_id"]) == 3 == counts["trajectories"]
    assert sorted(trajectories["split"]) == ["test", "train", "validation"]  # one each, of 3
    spiral = trajectories["trajectory_id"].index(trajectory_id(SPIRAL))
    assert TrajectorySpec.model_validate_json(trajectories["spec"][spiral]) == SPIRAL
    assert trajectories["center_z"][spiral] == 0.35 and trajectories["duration"][spiral] == 3.0
    card = (tmp_path / "dataset" / "README.md").read_text()
    assert "qdd_A1..A7" in card and "NaN on each episode's last tick" in card
    assert f"run_id `{run_id}`, behind KUKA's FRI torque interface" in card
    assert "`u_motor_A1..A7` (N*m): torque the motors exerted" in card


@pytest.mark.slow
def test_two_runs_in_directories_of_one_name_keep_every_episode(
    run_dir: Path, twin_dir: Path, tmp_path: Path
) -> None:
    assert run_dir.name == twin_dir.name and run_dir != twin_dir
    counts = build([run_dir, twin_dir], tmp_path / "both")
    alone = [  # the twin has one trajectory: it alone is all train
        build([run], tmp_path / f"alone-{i}", split=(1, 0, 0))["episodes"]
        for i, run in enumerate((run_dir, twin_dir))
    ]
    assert counts["episodes"] == sum(alone) and counts["runs"] == 2
    assert assert_ticks_are_the_logs(tmp_path / "both") == sum(alone)
    _, episodes, _ = tables(tmp_path / "both")
    assert set(episodes["run"]) == {"generic"} and len(set(episodes["run_id"])) == 2
    card = (tmp_path / "both" / "README.md").read_text()
    twin_id = read_identity(twin_dir / RUN_JSON).run_id
    assert f"run_id `{twin_id}`, on a plain torque interface (`u_motor` is `u`)" in card


def test_a_run_given_twice_or_copied_is_refused(run_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(DuplicateEpisodes, match="the same run"):
        build([run_dir, run_dir], tmp_path / "twice")
    copy = tmp_path / "copy" / "generic"
    shutil.copytree(run_dir, copy)
    with pytest.raises(DuplicateEpisodes, match="a copy of one"):
        build([run_dir, copy], tmp_path / "copied")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["copy"]


def test_a_run_without_a_run_id_is_given_one(run_dir: Path, tmp_path: Path) -> None:
    old = tmp_path / "old"
    shutil.copytree(run_dir, old)
    # As a run from before run ids (whose checkpoint would carry none: this one's would, so
    # it goes too; opening the run pins an id-less checkpoint, analytic.checkpoint tests that).
    (old / RUN_JSON).unlink()
    (old / "checkpoint.pkl").unlink()
    build([old], tmp_path / "dataset", split=(0.5, 0, 0.5))
    run_id = read_identity(old / RUN_JSON).run_id
    assert run_id != read_identity(run_dir / RUN_JSON).run_id
    _, episodes, _ = tables(tmp_path / "dataset")
    assert set(episodes["run_id"]) == {run_id}


@pytest.mark.slow
def test_the_split_is_by_trajectory(run_dir: Path, twin_dir: Path, tmp_path: Path) -> None:
    build([twin_dir, run_dir], tmp_path / "dataset", split=(0.4, 0.3, 0.3), split_seed=7)
    ticks, episodes, trajectories = tables(tmp_path / "dataset")
    assert set(ticks["split"]) <= set(SPLITS) and set(episodes["split"]) <= set(SPLITS)
    for table in (ticks, episodes):
        parts: dict[str, set[str]] = {}
        for tid, split in zip(table["trajectory_id"], table["split"], strict=True):
            parts.setdefault(tid, set()).add(split)
        assert all(len(splits) == 1 for splits in parts.values())  # never in two parts
    # The twins' shared spiral is one trajectory, whichever run it came from.
    assert len(trajectories["trajectory_id"]) == 3
    assert sorted(trajectories["split"]) == ["test", "train", "validation"]
    # The order the runs are given in does not matter.
    build([run_dir, twin_dir], tmp_path / "again", split=(0.4, 0.3, 0.3), split_seed=7)
    assert tables(tmp_path / "again")[2]["split"] == trajectories["split"]


def test_split_counts_round_and_fill_every_positive_part() -> None:
    assert split_counts((0.6, 0.2, 0.2), 10) == [6, 2, 2]
    assert split_counts((0.6, 0.2, 0.2), 3) == [1, 1, 1]
    assert split_counts((0.6, 0.2, 0.2), 4) == [2, 1, 1]
    assert split_counts((0.5, 0, 0.5), 2) == [1, 0, 1]
    assert split_counts((1, 0, 0), 1) == [1, 0, 0]
    assert split_counts((0.9, 0.05, 0.05), 3) == [1, 1, 1]
    with pytest.raises(BadSplit, match="only 2 trajectories"):
        split_counts((0.6, 0.2, 0.2), 2)
    for bad in ((0.5, 0.5, 0.5), (1.2, -0.2, 0), (float("nan"), 0.5, 0.5)):
        with pytest.raises(BadSplit, match="summing to 1"):
            split_counts(bad, 10)
    ids = [f"{n:012x}" for n in range(20)]
    splits = assign_splits(ids, (0.6, 0.2, 0.2), seed=0)
    assert assign_splits(ids[::-1], (0.6, 0.2, 0.2), seed=0) == splits  # order-free
    assert sorted(splits.values()).count("train") == 12
    assert assign_splits(ids, (0.6, 0.2, 0.2), seed=1) != splits  # the seed deals anew


def test_every_column_has_a_unit(run_dir: Path, tmp_path: Path) -> None:
    build([run_dir], tmp_path / "dataset")
    for name in ("ticks", "episodes", "trajectories"):
        schema = pq.read_schema(tmp_path / "dataset" / f"{name}.parquet")
        assert all(b"unit" in (field.metadata or {}) for field in schema), name
        assert schema.metadata[b"control_period"] == b"0.002"
        assert schema.metadata[b"dataset_version"] == b"5"
    ticks = pq.read_schema(tmp_path / "dataset" / "ticks.parquet")
    expected = {
        "t": b"s",
        "q_A1": b"rad",
        "qd_A2": b"rad/s",
        "qdd_A3": b"rad/s^2",
        "tau_A4": b"N*m",
        "u_A5": b"N*m",
        "u_motor_A6": b"N*m",
        "theta_A6": b"rad",
        "theta_d_A7": b"rad/s",
        "ee_des_z": b"m",
        "episode_id": b"",
        "split": b"",
    }
    assert {name: ticks.field(name).metadata[b"unit"] for name in expected} == expected
    episodes = pq.read_schema(tmp_path / "dataset" / "episodes.parquet")
    assert episodes.field("kp_A1").metadata[b"unit"] == b"N*m/rad"
    assert episodes.field("f_acc").metadata[b"unit"] == b"m"


def test_the_logs_are_hard_links_to_the_runs(run_dir: Path, tmp_path: Path) -> None:
    build([run_dir], tmp_path / "dataset")
    _, episodes, _ = tables(tmp_path / "dataset")
    assert episodes["episode_id"]
    for episode_id in episodes["episode_id"]:
        job = episode_id.split("-", 1)[1]
        ours = (tmp_path / "dataset" / "episodes" / f"{episode_id}.mcap").stat()
        theirs = (run_dir / "episodes" / f"{job}.mcap").stat()
        assert (ours.st_dev, ours.st_ino) == (theirs.st_dev, theirs.st_ino)
    assert "hard links to the runs' own logs" in (tmp_path / "dataset" / "README.md").read_text()


@pytest.mark.slow
def test_the_rerun_runs_every_selected_controller_on_each_trajectory(
    run_dir: Path, endpoint: str, tmp_path: Path
) -> None:
    counts = build(
        [run_dir], tmp_path / "dataset", "knee", rerun_trajectories=RERUN, farm=farm_at(endpoint)
    )
    assert counts["rerun"] == 1 * len(RERUN) and counts["episodes"] == 3 + len(RERUN)
    assert assert_ticks_are_the_logs(tmp_path / "dataset") == counts["episodes"]
    _, episodes, trajectories = tables(tmp_path / "dataset")
    reruns = [i for i, source in enumerate(episodes["source"]) if source == "rerun"]
    assert len(reruns) == len(RERUN)
    assert {episodes["run"][i] for i in reruns} == {"rerun"}
    assert {episodes["run_id"][i] for i in reruns} == {read_identity(run_dir / RUN_JSON).run_id}
    assert {episodes["trajectory_id"][i] for i in reruns} == {trajectory_id(t) for t in RERUN}
    tuned = [i for i, source in enumerate(episodes["source"]) if source == "tuning"]
    assert {episodes["kp_A1"][i] for i in reruns} == {episodes["kp_A1"][i] for i in tuned}
    assert len(trajectories["trajectory_id"]) == 5
    assert not (tmp_path / "dataset" / RERUN_DIR).exists()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["dataset"]  # no staging left


@pytest.mark.slow
def test_the_rerun_through_the_cli(run_dir: Path, endpoint: str, tmp_path: Path) -> None:
    rerun = tmp_path / "rerun.json"
    rerun.write_text(json.dumps([t.model_dump(mode="json") for t in RERUN[:1]]))
    out = tmp_path / "dataset"
    command = [str(run_dir), "--out", str(out), "--select", "knee", "--split", "0.5,0,0.5"]
    result = subprocess.run(
        [*ANALYTIC, *command, "--rerun", str(rerun), "--connect", endpoint],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"{out}: 4 episodes, 1 of them rerun in ")
    _, episodes, _ = tables(out)
    assert sorted(episodes["source"]) == ["rerun", "tuning", "tuning", "tuning"]


def test_bad_rerun_trajectories_are_refused_before_anything_runs(
    run_dir: Path, tmp_path: Path
) -> None:
    for trajectories, problem in (
        ([RERUN[0], RERUN[1], RERUN[0]], "trajectory 3 repeats trajectory 1"),
        ([TrajectorySpec(duration=0.5)], re.escape("trajectory 1 (spiral, 0.5 s): the 0.5 s")),
    ):
        with pytest.raises(BadRerun, match=problem):
            build([run_dir], tmp_path / "dataset", rerun_trajectories=trajectories)
    assert list(tmp_path.iterdir()) == []


def test_the_knee_is_one_controller_on_every_trajectory(run_dir: Path, tmp_path: Path) -> None:
    counts = build([run_dir], tmp_path / "knee", selection="knee")
    assert counts["controllers"] == 1 and counts["episodes"] == 3


def test_the_knee_is_the_member_analytic_export_takes(run_dir: Path) -> None:
    """One knee rule: `--select knee` takes the controller `analytic export --member knee`
    writes."""
    [knee] = select(read_run(run_dir), "knee")
    exported = controller(run_dir, "knee")
    assert (knee.kp, knee.kd) == (exported.kp, exported.kd) and exported.member.selected == "knee"


def test_a_dataset_is_never_overwritten_or_left_half_made(run_dir: Path, tmp_path: Path) -> None:
    (tmp_path / "taken").mkdir()
    with pytest.raises(FileExistsError):
        build([run_dir], tmp_path / "taken")
    empty = tmp_path / "empty-run"
    TuningRun.create(empty, CONFIG).close()
    with pytest.raises(NoEpisodes):
        build([empty], tmp_path / "nothing")
    with pytest.raises(BadSplit):  # fractions that do not sum to 1
        build([run_dir], tmp_path / "nothing", split=(0.2, 0.2, 0.2))
    assert sorted(path.name for path in tmp_path.iterdir()) == ["empty-run", "taken"]


def test_the_documented_example_runs_on_a_dataset(
    run_dir: Path, twin_dir: Path, tmp_path: Path
) -> None:
    build([run_dir, twin_dir], tmp_path / "dataset")
    docs = (Path(__file__).parents[3] / "docs" / "dataset.md").read_text()
    [example] = re.findall(r"```python\n(.*?)```", docs, flags=re.DOTALL)
    script = tmp_path / "example.py"
    script.write_text(example)
    run = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "dataset")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    # It fits on the train trajectories' ticks and scores on the test ones', those with a
    # smoothed acceleration: the split column, not the order of the rows.
    ticks = pq.read_table(tmp_path / "dataset" / "ticks.parquet", columns=["split", "qdd_sg_A1"])
    split = np.array(ticks.column("split").to_pylist())
    usable = ~np.isnan(ticks.column("qdd_sg_A1").to_numpy())
    train, test = (int((usable & (split == part)).sum()) for part in ("train", "test"))
    assert train and test
    lines = run.stdout.splitlines()
    assert lines[0] == f"fit on {train} train ticks, scored on {test} test ticks"
    assert lines[1].startswith("torque RMSE per joint (N·m): [")
    assert lines[2].startswith("torque nMSE per joint: [")
    assert len(lines) == 3


def analytic(
    arguments: Sequence[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> tuple[int, str]:
    """`analytic dataset ARGUMENTS` through the console script's own entry point, in this
    process (a process each would cost seconds of imports): its exit status and stderr."""
    monkeypatch.setattr(sys, "argv", ["analytic", "dataset", *arguments])
    try:
        with pytest.raises(SystemExit) as exit:
            main()
    finally:
        interrupts.uninstall()  # the command took Ctrl-C over for its process: give it back
    return int(exit.value.code or 0), capsys.readouterr().err


def test_bad_split_and_rerun_options_are_one_line_and_write_nothing(
    run_dir: Path,
    twin_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    monkeypatch.chdir(tmp_path)
    files = {
        "missing.json": None,
        "not-json.json": "[{",
        "not-a-list.json": '{"kind": "spiral"}',
        "empty.json": "[]",
        "unknown-field.json": '[{"kind": "spiral", "duraton": 3}]',
        "too-fast.json": '[{"kind": "spiral", "duration": 0.5}]',
        "repeated.json": '[{"kind": "fourier"}, {"kind": "fourier"}]',
    }
    for name, content in files.items():
        if content is not None:
            (tmp_path / name).write_text(content)
    run, twin = str(run_dir), str(twin_dir)
    splits = ("0.5,0.5", "a,b,c", "0.6,0.6,-0.2", "0.2,0.2,0.2", "nan,0.5,0.5")
    too_few = "--split: 3 non-empty parts (train/validation/test) but the dataset has only 1 "
    too_fast = "--rerun: trajectory 1 (spiral, 0.5 s): the 0.5 s spiral is too fast"
    cases = [
        *(([run, "--out", "out", "--split", split], "--split: ") for split in splits),
        ([twin, "--out", "out"], too_few),
        *(([run, "--out", "out", "--rerun", name], "--rerun: ") for name in files),
        ([run, "--out", "out", "--rerun", "too-fast.json"], too_fast),
        ([run, "--out", "out", "--rerun", "repeated.json"], "--rerun: trajectory 2 repeats"),
        ([run, run, "--out", "out"], f"{run!r} and {run!r} are the same run"),
        ([run, "--out", "out", "--local"], "--connect and --local need --rerun"),
    ]
    for arguments, message in cases:
        status, stderr = analytic(arguments, monkeypatch, capsys)
        assert status == 2, stderr
        assert stderr.startswith(f"analytic: error: {message}"), stderr
        assert stderr.count("\n") == 1 and "Traceback" not in stderr
    assert sorted(os.listdir(tmp_path)) == sorted(name for name in files if files[name])


def test_an_out_under_a_file_is_refused_before_the_runs_are_read(tmp_path: Path) -> None:
    """Not "File exists" from mkdir once a rerun has run: the file in the way, at once."""
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.json").write_text("{}")  # a run, as far as this check looks
    (tmp_path / "notes").write_text("mine")
    for out, says in (
        ("notes/data", "--out: cannot write 'notes/data': 'notes' is a file"),
        ("notes/a/data", "--out: cannot write 'notes/a/data': 'notes' is a file"),
    ):
        run = subprocess.run(
            [*ANALYTIC, "run", "--out", out],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=tmp_path,
        )
        assert run.returncode == 2, run.stderr
        assert run.stderr == f"analytic: error: {says}\n"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["notes", "run"]


@pytest.mark.slow
def test_dataset_command_errors_are_one_line(tmp_path: Path) -> None:
    run = subprocess.run(
        [*ANALYTIC, "nowhere", "--out", "x"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert run.returncode == 2
    assert run.stderr == "analytic: error: 'nowhere' holds no run (no config.json)\n"


@pytest.mark.slow
def test_dataset_of_an_unreadable_run_names_it_in_one_line(run_dir: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("config.json", "run.json", "history.csv", "evaluated.csv"):
        (broken / name).write_bytes((run_dir / name).read_bytes())
    (broken / "front.json").write_text("{not json")
    run = subprocess.run(
        [*ANALYTIC, str(broken), "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2
    assert run.stderr.startswith(f"analytic: error: {str(broken)!r}: unreadable run")
    assert run.stderr.count("\n") == 1 and not (tmp_path / "x").exists()


@pytest.mark.slow
def test_dataset_of_a_damaged_log_names_it_in_one_line(run_dir: Path, tmp_path: Path) -> None:
    """A log that is not one (cut short) or that holds no tick (which no worker writes: that
    one used to escape as a traceback from Parquet) is the run's problem, said in one line."""
    source = run_dir / read_run(run_dir).front[0].logs[0]  # a log the dataset takes
    log = read_episode(source)
    empty = dataclasses.replace(
        log,
        metadata=log.metadata.model_copy(update={"ticks_run": 0}),
        **{name: getattr(log, name)[:0] for name in ARRAYS},
    )
    damages = {
        "cut short": lambda path: path.write_bytes(source.read_bytes()[:5_000]),
        "no tick": lambda path: write_log(empty, path),
    }
    for damage, message in zip(
        damages, ("truncated MCAP file", "without a single tick"), strict=True
    ):
        broken = tmp_path / damage.replace(" ", "-")
        shutil.copytree(run_dir, broken)
        damaged = broken / source.relative_to(run_dir)
        damaged.unlink()  # a hard link to the run's own log, maybe: never write through it
        damages[damage](damaged)
        run = subprocess.run(
            [*ANALYTIC, str(broken), "--out", str(tmp_path / "x"), "--split", "1,0,0"],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert run.returncode == 2, run.stderr
        assert run.stderr == f"analytic: error: {damaged}: {run.stderr.split(': ', 3)[-1]}"
        assert message in run.stderr and run.stderr.count("\n") == 1
        assert not (tmp_path / "x").exists()


# --- clean by construction, and more data from the same controllers ---------------------------


def test_the_smoothed_acceleration_is_the_fit_of_q_within_each_episode(
    run_dir: Path, tmp_path: Path
) -> None:
    """qdd_sg is the Savitzky-Golay fit of each episode's own q: a cubic's second derivative,
    so on a cubic it is exact, and no window reaches across two episodes."""
    t = np.arange(200) * 0.002
    cubic = np.column_stack([(k + 1) * t**3 - t**2 for k in range(7)])
    np.testing.assert_allclose(
        dataset_module.smoothed_acceleration(cubic, 0.002),
        np.column_stack([(k + 1) * 6 * t - 2 for k in range(7)]),
        atol=1e-8,
    )
    assert np.isnan(dataset_module.smoothed_acceleration(cubic[:10], 0.002)).all()
    build([run_dir], tmp_path / "dataset", "knee")
    ticks, _, _ = tables(tmp_path / "dataset")
    ids = np.asarray(ticks["episode_id"])
    for episode in sorted(set(ids))[:2]:
        mine = ids == episode
        q = np.column_stack([np.asarray(ticks[f"q_{j}"])[mine] for j in JOINT_NAMES])
        qdd_sg = np.column_stack([np.asarray(ticks[f"qdd_sg_{j}"])[mine] for j in JOINT_NAMES])
        np.testing.assert_array_equal(qdd_sg, dataset_module.smoothed_acceleration(q, 0.002))


def test_rough_episodes_are_left_out_unless_asked_and_flagged(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With the calm threshold between the front's episodes' chatter, those above it are left
    out (their logs too), counted on the card; --include-rough keeps them with calm false."""
    every = build([run_dir], tmp_path / "every", "front", include_rough=True)
    _, rows, _ = tables(tmp_path / "every")
    assert all(rows["calm"]) and every["rough"] == 0  # a tuned front is calm
    chatter = sorted(rows["chatter"])
    threshold = chatter[len(chatter) // 2]
    monkeypatch.setattr(dataset_module, "CALM_CHATTER", threshold)
    rough = sum(value > threshold for value in chatter)
    assert 0 < rough < len(chatter)
    clean = build([run_dir], tmp_path / "clean", "front")
    _, kept, _ = tables(tmp_path / "clean")
    assert clean["rough_left_out"] == rough and len(kept["episode_id"]) == len(chatter) - rough
    assert all(kept["calm"]) and max(kept["chatter"]) <= threshold
    assert len(list((tmp_path / "clean" / "episodes").iterdir())) == len(chatter) - rough
    card = " ".join((tmp_path / "clean" / "README.md").read_text().split())  # wrapped lines
    assert f"{rough} episodes that chatter or diverged were left out" in card
    flagged = build([run_dir], tmp_path / "flagged", "front", include_rough=True)
    _, both, _ = tables(tmp_path / "flagged")
    assert flagged["rough"] == rough and flagged["rough_left_out"] == 0
    assert [not calm for calm in both["calm"]] == [value > threshold for value in both["chatter"]]


@pytest.mark.slow
def test_excitations_on_plant_variants_through_the_cli(
    run_dir: Path, endpoint: str, tmp_path: Path
) -> None:
    """--excitations N --plants K: the knee on N fourier excitations, on its run's plant and K
    held-out variants of it, each episode's plant in its row."""
    out = tmp_path / "dataset"
    command = [str(run_dir), "--out", str(out), "--select", "knee", "--split", "0.5,0,0.5"]
    # The module's toy run is barely tuned: kept whatever it does on a 10 s excitation.
    command += ["--infeasible", "--include-rough", "--connect", endpoint]
    result = subprocess.run(
        [*ANALYTIC, *command, "--excitations", "1", "--plants", "2"],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert result.returncode == 0, result.stderr
    ticks, episodes, trajectories = tables(out)
    reruns = [i for i, source in enumerate(episodes["source"]) if source == "rerun"]
    assert len(reruns) == 3  # one excitation on three plants
    ids = sorted(episodes["episode_id"][i] for i in reruns)
    assert sum("-rerun-p1-" in i for i in ids) == sum("-rerun-p2-" in i for i in ids) == 1
    nominal = read_run(run_dir).config.plant
    variants = dataset_module.plant_variants(nominal, 2, 0)
    models = {PlantSpec.model_validate_json(episodes["model"][i]) for i in reruns}
    assert models == {nominal, *variants} and len(models) == 3
    excitation = dataset_module.excitations(1)[0]
    assert trajectory_id(excitation) in trajectories["trajectory_id"]
    card = (out / "README.md").read_text()
    assert "--plants 2" in card
    # One plant per part: the variants' episodes in their trajectory's part, suffixed, ticks too.
    part = dict(zip(trajectories["trajectory_id"], trajectories["split"], strict=True))
    split_of = {}
    for i in range(len(episodes["episode_id"])):
        variant = PlantSpec.model_validate_json(episodes["model"][i]) != nominal
        split_of[episodes["episode_id"][i]] = part[episodes["trajectory_id"][i]] + "_variants" * (
            variant
        )
        assert episodes["split"][i] == split_of[episodes["episode_id"][i]]
        assert variant == ("-rerun-p" in episodes["episode_id"][i])
    assert {(e, s) for e, s in zip(ticks["episode_id"], ticks["split"], strict=True)} == set(
        split_of.items()
    )
    assert "2 episodes on a plant other than their run's" in " ".join(card.split())


def test_plants_without_a_rerun_is_one_line(run_dir: Path, tmp_path: Path) -> None:
    result = subprocess.run(
        [*ANALYTIC, str(run_dir), "--out", str(tmp_path / "d"), "--plants", "2"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode != 0 and not (tmp_path / "d").exists()
    assert result.stderr.strip().count("\n") == 0 and "--plants" in result.stderr


# --- another arm: the UR5e (6 joints) ------------------------------------------------------------


@pytest.mark.slow
def test_a_ur5e_dataset_is_its_episodes_under_its_joints_names(
    ur5e_dir: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ur5e"
    # A toy run's front, kept whatever it does: the columns are what is tested.
    counts = build([ur5e_dir], out, infeasible=True, include_rough=True)
    assert assert_ticks_are_the_logs(out) == counts["episodes"] >= 3
    joints = robot_of("ur5e").joint_names
    schema = pq.read_schema(out / "ticks.parquet")
    angles = [name for name in schema.names if name.startswith("q_") and "_des_" not in name]
    assert angles == [f"q_{joint}" for joint in joints]
    assert not any(name.endswith("_A1") for name in schema.names)
    assert schema.field("tau_wrist_3_joint").metadata[b"unit"] == b"N*m"
    assert schema.field("qd_des_shoulder_lift_joint").metadata[b"unit"] == b"rad/s"
    for table in ("ticks", "episodes", "trajectories"):
        metadata = pq.read_schema(out / f"{table}.parquet").metadata
        assert metadata[b"robot"] == b"ur5e"
        assert json.loads(metadata[b"joint_names"]) == list(joints)
    names = pq.read_schema(out / "episodes.parquet").names
    assert "kp_shoulder_pan_joint" in names and "kd_wrist_3_joint" in names
    assert "kp_A1" not in names
    card = (out / "README.md").read_text()
    assert "simulated Universal Robots UR5e (6 joints;" in card
    assert "`q_{shoulder_pan_joint,shoulder_lift_joint," in card and "iiwa" not in card
    assert "UR direct torque control (gravity added as FRI does)" in card


@pytest.mark.slow
def test_runs_of_two_arms_make_no_dataset(run_dir: Path, ur5e_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(dataset_module.MixedArms, match=r"of 2 arms \(iiwa14, ur5e\)"):
        build([run_dir, ur5e_dir], tmp_path / "both")
    assert not (tmp_path / "both").exists() and list(tmp_path.iterdir()) == []
