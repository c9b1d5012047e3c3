"""Small learning datasets made by hand, in the contract of analytic/dataset.py: real MuJoCo
episodes of fourier excitations, written as ticks.parquet and episodes.parquet.

Only the columns analytic/learning.py reads, plus the identifiers; each trajectory (one seed) is
one episode, so splitting by episode is splitting by trajectory, as the real builder does. The
motors' whole torque, u_motor, is the builder's own (worker.episode.motor_torque).
"""

from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gainfarm.analytic.data.dataset import smoothed_acceleration
from gainfarm.analytic.data.dataset_columns import arm_metadata
from gainfarm.models import robot_of
from gainfarm.schemas import EpisodeSpec, PDGains, TrajectorySpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD
from gainfarm.worker.episode import motor_torque, run_episode

# Gains that track the fourier excitations within some 0.05 rad and keep the realistic plant calm
# (peak link acceleration some 25 rad/s²), as a tuned controller does. tests.helpers'
# TRACKING_GAINS make its elastic joints chatter (1,700 rad/s², torques at their limits) on most
# seeds: data no rigid-body model explains.
CALM_GAINS = PDGains(kp=(1000, 1000, 600, 600, 200, 100, 50), kd=(30, 30, 20, 20, 5, 2.5, 1))
SIGNALS = ("q", "qd", "u", "tau", "theta", "theta_d", "q_des", "qd_des")

# (seed, split) per episode: enough variety for a network to beat the mean, and fast to simulate.
SPLITS: tuple[tuple[int, str], ...] = (
    *((seed, "train") for seed in range(6)),
    (6, "validation"),
    (7, "test"),
    (8, "test"),
)


def calm_gains(robot: str) -> PDGains:
    """The gains `episode` tracks with on `robot`: CALM_GAINS on the iiwa 14; another arm's own
    default gains (its module's rule: the iiwa's A1, full torque at 0.15 rad), which track the
    UR5e's fourier excitations within some 0.05 rad, calm."""
    return CALM_GAINS if robot == DEFAULT_ROBOT else robot_of(robot).default_gains


@lru_cache(maxsize=8)
def episode(plant: PlantSpec, seed: int, duration: float) -> EpisodeLog:
    """A fourier excitation tracked with CALM_GAINS and gravity compensation on `plant` (a
    feed-forward, or the robot's own behind FRI); cached, as several tests write datasets from
    the same episodes."""
    spec = EpisodeSpec(
        gains=calm_gains(plant.robot),
        trajectory=TrajectorySpec(kind="fourier", seed=seed, duration=duration),
        plant=plant,
        gravity_compensation=plant.interface == "torque",
    )
    log = run_episode(spec)
    assert not log.metadata.diverged, log.metadata.divergence
    return log


def write_dataset(
    path: Path,
    plant: PlantSpec,
    splits: Sequence[tuple[int, str]] = SPLITS,
    duration: float = 2.0,
    motor_column: bool = True,
    smoothed: bool = True,
    rough: Sequence[int] = (),
) -> Path:
    """Write a dataset directory at `path` with one episode per (seed, split); return `path`.
    Without `motor_column`, as a dataset from before u_motor; without `smoothed`, as one from
    before qdd_sg and the calm flag. The episodes of the seeds in `rough` are flagged not calm
    (whatever they are: the flag's meaning is the builder's, tested in test_dataset.py). An
    iiwa 14's is as a dataset from before other arms (no arm in its metadata); another arm's
    columns are its joints and its metadata names it, as the builder writes them."""
    joints = robot_of(plant).joint_names
    path.mkdir(parents=True)
    ticks, rows = [], []
    for seed, split in splits:
        log = episode(plant, seed, duration)
        episode_id = f"fourier-{seed}"
        columns: dict[str, object] = {
            "episode_id": [episode_id] * log.ticks,
            "trajectory_id": [f"fourier-seed{seed}"] * log.ticks,
            "split": [split] * log.ticks,
            "t": log.t,
        }
        # The contract's acceleration: forward differences of the measured velocity, NaN last.
        qdd = np.full_like(log.qd, np.nan)
        qdd[:-1] = np.diff(log.qd, axis=0) / CONTROL_PERIOD
        signals = [(name, getattr(log, name)) for name in SIGNALS] + [("qdd", qdd)]
        signals += [("u_motor", motor_torque(log))] * motor_column
        signals += [("qdd_sg", smoothed_acceleration(log.q, CONTROL_PERIOD))] * smoothed
        for signal, values in signals:
            for index, joint in enumerate(joints):
                columns[f"{signal}_{joint}"] = values[:, index]
        ticks.append(pa.table(columns))
        row = {"episode_id": episode_id, "split": split, "model": plant.model_dump_json()}
        rows.append(row | ({"calm": seed not in rough} if smoothed else {}))
    table = pa.concat_tables(ticks)
    if plant.robot != DEFAULT_ROBOT:
        table = table.replace_schema_metadata(arm_metadata(plant.robot, joints))
    pq.write_table(table, path / "ticks.parquet")
    pq.write_table(pa.Table.from_pylist(rows), path / "episodes.parquet")
    return path
