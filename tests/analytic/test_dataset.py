"""The dataset: what goes in is exactly what the episodes logged."""

import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from analytic.config import RunConfig
from analytic.dataset import NoEpisodes, build
from analytic.farm import FarmClient
from analytic.local import local_farm
from analytic.run import TuningRun
from schemas import TrajectorySpec
from schemas.mcap_episode import read_episode
from schemas.robot import JOINT_NAMES

CONFIG = RunConfig(
    pop=4,
    seed=3,
    trajectories=(TrajectorySpec(duration=3.0), TrajectorySpec(kind="random", duration=3.0)),
    generations=2,
)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    directory = tmp_path_factory.mktemp("runs") / "generic"
    run = TuningRun.create(directory, CONFIG)
    with local_farm(workers=2) as endpoint, FarmClient([endpoint], "dataset", directory) as farm:
        run.run(farm)
    yield directory


def test_the_tick_table_is_the_episodes_tick_by_tick(run_dir: Path, tmp_path: Path) -> None:
    counts = build([run_dir], tmp_path / "dataset")
    ticks = pq.read_table(tmp_path / "dataset" / "ticks.parquet").to_pydict()
    episodes = pq.read_table(tmp_path / "dataset" / "episodes.parquet").to_pydict()
    logs = sorted((tmp_path / "dataset" / "episodes").glob("*.mcap"))
    assert counts["episodes"] == len(logs) == len(episodes["episode_id"]) >= 2
    assert counts["ticks"] == len(ticks["t"])
    assert {"spiral", "random"} == set(episodes["trajectory"])
    episode_ids = np.array(ticks["episode_id"])
    for path in logs:
        log = read_episode(path)
        rows = episode_ids == path.stem
        assert rows.sum() == log.ticks
        np.testing.assert_array_equal(np.array(ticks["t"])[rows], log.t)
        for index, joint in enumerate(JOINT_NAMES):
            for signal in ("q", "qd", "tau", "u", "theta", "theta_d", "q_des", "qd_des"):
                values = np.array(ticks[f"{signal}_{joint}"])[rows]
                np.testing.assert_array_equal(values, getattr(log, signal)[:, index])
        for index, axis in enumerate("xyz"):
            np.testing.assert_array_equal(np.array(ticks[f"ee_{axis}"])[rows], log.ee[:, index])
        row = episodes["episode_id"].index(path.stem)
        assert episodes["kp_A1"][row] == log.metadata.spec.gains.kp[0]
        assert episodes["ticks"][row] == log.ticks
    assert "episodes" in (tmp_path / "dataset" / "README.md").read_text()


def test_the_knee_is_one_controller_on_every_trajectory(run_dir: Path, tmp_path: Path) -> None:
    counts = build([run_dir], tmp_path / "knee", selection="knee")
    assert counts["controllers"] == 1 and counts["episodes"] == 2


def test_a_dataset_is_never_overwritten_or_left_half_made(run_dir: Path, tmp_path: Path) -> None:
    (tmp_path / "taken").mkdir()
    with pytest.raises(FileExistsError):
        build([run_dir], tmp_path / "taken")
    empty = tmp_path / "empty-run"
    TuningRun.create(empty, CONFIG)
    with pytest.raises(NoEpisodes):
        build([empty], tmp_path / "nothing")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["empty-run", "taken"]


def test_the_documented_example_runs_on_a_dataset(run_dir: Path, tmp_path: Path) -> None:
    build([run_dir], tmp_path / "dataset")
    docs = (Path(__file__).parents[2] / "docs" / "dataset.md").read_text()
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
    assert run.stdout.startswith("torque RMSE per joint (N·m): [")


def test_dataset_command_errors_are_one_line(tmp_path: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "analytic", "dataset", "nowhere", "--out", "x"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert run.returncode == 2
    assert run.stderr == "analytic: error: 'nowhere' holds no run (no config.json)\n"


def test_dataset_of_an_unreadable_run_names_it_in_one_line(run_dir: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("config.json", "history.csv", "evaluated.csv"):
        (broken / name).write_bytes((run_dir / name).read_bytes())
    (broken / "front.json").write_text("{not json")
    run = subprocess.run(
        [sys.executable, "-m", "analytic", "dataset", str(broken), "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2
    assert run.stderr.startswith(f"analytic: error: {str(broken)!r}: unreadable run")
    assert run.stderr.count("\n") == 1 and not (tmp_path / "x").exists()
