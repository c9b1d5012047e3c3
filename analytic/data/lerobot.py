"""A release's ticks in LeRobot's dataset layout, codebase version v3.0, for the tools that read
it (`--format lerobot`).

Written from the layout LeRobot's own code defines (lerobot/datasets/utils.py, dataset_metadata.py
and io_utils.py: the v3.0 paths, `DatasetInfo`, the episodes' metadata), without importing
LeRobot: it requires PyTorch, whose wheels (gigabytes of CUDA packages) this project's machines
and CI do not install. The test reads the export back with a reader of its own, written from the
same layout.

    meta/info.json                          codebase_version, fps, robot_type, features, splits,
                                            total_episodes, total_frames, chunks_size, data_path
    meta/stats.json                         per feature: mean, std, min, max, count (train only)
    meta/tasks.parquet                      the one task
    meta/episodes/chunk-000/file-000.parquet  one row per episode: where its frames are
    data/chunk-XXX/file-YYY.parquet         the frames, whole episodes per file

A frame is a tick. The episodes are ordered by split (train, validation, test, then their
_variants), so that each split is the contiguous range of episode indices info.json's `splits`
gives.
"""

import json
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gainfarm.analytic.data.arm import robot_type
from gainfarm.analytic.data.loader import ALL_SPLITS, dataset_arm
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.trajectory import CONTROL_PERIOD

CODEBASE_VERSION = "v3.0"
FPS = round(1 / CONTROL_PERIOD)
CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
DATA_PATH = "data/" + CHUNK_FILE + ".parquet"
EPISODES_PATH = "meta/episodes/" + CHUNK_FILE + ".parquet"
INFO_PATH, STATS_PATH, TASKS_PATH = "meta/info.json", "meta/stats.json", "meta/tasks.parquet"
DATA_FILE_SIZE_IN_MB = 100  # LeRobot's default cap on a data file
VIDEO_FILE_SIZE_IN_MB = 200  # info.json carries it (LeRobot checks it is positive); no videos
TASK = "track the reference trajectory with a tuned PD controller"
# Each feature → the ticks.parquet signals it stacks, per joint of the arm (q_A1..A7, then
# qd_A1..A7 on the iiwa 14).
FEATURES: dict[str, tuple[str, ...]] = {
    "observation.state": ("q", "qd"),
    "observation.acceleration": ("qdd_sg",),
    "observation.effort": ("tau",),
    "observation.motor_state": ("theta", "theta_d"),
    "observation.reference": ("q_des", "qd_des"),
    "action": ("u_motor",),
}
# What LeRobot adds to every frame (its DEFAULT_FEATURES): scalars, shape (1,).
INDEX_FEATURES = {
    "timestamp": "float32",
    "frame_index": "int64",
    "episode_index": "int64",
    "index": "int64",
    "task_index": "int64",
}


@dataclass(frozen=True)
class LerobotLayout:
    """How the LeRobot copy is cut into files: LeRobot's own defaults unless a test asks for
    small files to see its chunks."""

    chunks_size: int = 1000  # files per chunk directory (LeRobot's DEFAULT_CHUNK_SIZE)
    file_frames: int | None = None  # frames per data file at most; None: LeRobot's 100 MB


DEFAULT_LAYOUT = LerobotLayout()


def feature_names(feature: str, joints: Sequence[str]) -> list[str]:
    """The ticks.parquet columns `feature` stacks, for an arm of `joints`."""
    return [f"{signal}_{joint}" for signal in FEATURES[feature] for joint in joints]


def features(joints: Sequence[str]) -> dict[str, dict[str, Any]]:
    """info.json's features, for an arm of `joints`: each with its dtype, shape and names."""
    found: dict[str, dict[str, Any]] = {
        name: {
            "dtype": "float32",
            "shape": [len(feature_names(name, joints))],
            "names": feature_names(name, joints),
        }
        for name in FEATURES
    }
    for name, dtype in INDEX_FEATURES.items():
        found[name] = {"dtype": dtype, "shape": [1], "names": None}
    return found


def frame_bytes(joints: Sequence[str]) -> int:
    """A frame's size uncompressed: what the files' frame budget is reckoned from."""
    return 4 * sum(len(feature_names(name, joints)) for name in FEATURES) + 4 + 8 * 4


@dataclass
class Moments:
    """Running mean, variance, min and max per dimension (Chan's pairwise update: one episode's
    block at a time, without keeping the split in memory). NaN-aware per dimension."""

    count: np.ndarray
    mean: np.ndarray
    m2: np.ndarray
    low: np.ndarray
    high: np.ndarray
    frames: int = 0

    @classmethod
    def empty(cls, width: int) -> "Moments":
        zeros = np.zeros(width)
        return cls(zeros.copy(), zeros.copy(), zeros.copy(), zeros + np.inf, zeros - np.inf)

    def add(self, block: np.ndarray) -> None:
        block = np.asarray(block, dtype=float).reshape(len(block), -1)
        finite = np.isfinite(block)
        count = finite.sum(axis=0).astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(count > 0, np.nansum(block, axis=0) / np.maximum(count, 1), 0.0)
            m2 = np.nansum(np.where(finite, block - mean, 0.0) ** 2, axis=0)
            total = self.count + count
            delta = mean - self.mean
            share = np.where(total > 0, count / np.maximum(total, 1), 0.0)
            self.m2 = self.m2 + m2 + delta**2 * self.count * share
            self.mean = self.mean + delta * share
        self.count = total
        self.low = np.fmin(self.low, np.where(finite, block, np.inf).min(axis=0))
        self.high = np.fmax(self.high, np.where(finite, block, -np.inf).max(axis=0))
        self.frames += len(block)

    def as_json(self) -> dict[str, list[float | None] | list[int]]:
        def shown(values: np.ndarray) -> list[float | None]:
            return [
                float(v) if c > 0 and math.isfinite(v) else None
                for v, c in zip(values, self.count, strict=True)
            ]

        std = np.sqrt(np.where(self.count > 0, self.m2 / np.maximum(self.count, 1), np.nan))
        return {
            "mean": shown(self.mean),
            "std": shown(std),
            "min": shown(self.low),
            "max": shown(self.high),
            "count": [self.frames],
        }


@dataclass
class Writer:
    """Frames gathered into data files of at most `file_frames`, whole episodes each (LeRobot
    starts a new file before an episode that would not fit), `chunks_size` files a chunk."""

    out: Path
    file_frames: int
    chunks_size: int
    blocks: list[pa.Table] = field(default_factory=list)
    pending: int = 0
    chunk_index: int = 0
    file_index: int = 0
    written: list[str] = field(default_factory=list)

    def place(self, frames: int) -> tuple[int, int]:
        """The chunk and file an episode of `frames` goes to, starting a new file if need be."""
        if self.pending and self.pending + frames > self.file_frames:
            self.flush()
            self.file_index += 1
            if self.file_index == self.chunks_size:
                self.chunk_index, self.file_index = self.chunk_index + 1, 0
        return self.chunk_index, self.file_index

    def add(self, block: pa.Table) -> None:
        self.blocks.append(block)
        self.pending += block.num_rows

    def flush(self) -> None:
        if not self.blocks:
            return
        path = DATA_PATH.format(chunk_index=self.chunk_index, file_index=self.file_index)
        (self.out / path).parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.concat_tables(self.blocks), self.out / path, compression="zstd")
        self.written.append(path)
        self.blocks, self.pending = [], 0


def _episodes(dataset: Path) -> list[dict[str, Any]]:
    """episodes.parquet's rows, ordered by split, then as the dataset has them."""
    names = pq.read_schema(dataset / "episodes.parquet").names
    wanted = ["episode_id", "trajectory_id", "split", "ticks"] + ["calm"] * ("calm" in names)
    rows = pq.read_table(dataset / "episodes.parquet", columns=wanted).to_pylist()
    order = {split: index for index, split in enumerate(ALL_SPLITS)}
    return sorted(rows, key=lambda row: order[row["split"]])  # stable: the dataset's order within


def _split_ticks(
    dataset: Path, split: str, joints: Sequence[str]
) -> Iterator[tuple[str, pa.Table]]:
    """Each episode of `split` with its ticks (the columns the features take, and t)."""
    columns = ["episode_id", "t"] + [
        name for feature in FEATURES for name in feature_names(feature, joints)
    ]
    table = pq.read_table(
        dataset / "ticks.parquet", columns=columns, filters=[("split", "==", split)]
    )
    ids = table["episode_id"].to_numpy(zero_copy_only=False)
    if not len(ids):
        return
    # An episode's ticks are contiguous in ticks.parquet (the builder writes them one by one).
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    ends = np.r_[starts[1:], len(ids)]
    for start, end in zip(starts, ends, strict=True):
        yield str(ids[start]), table.slice(start, end - start)


def _frames(
    ticks: pa.Table, episode_index: int, first: int, joints: Sequence[str]
) -> tuple[pa.Table, dict[str, np.ndarray]]:
    """An episode's frames, and each feature's float32 values (for the stats)."""
    n = ticks.num_rows
    values: dict[str, np.ndarray] = {}
    columns: dict[str, pa.Array] = {}
    for feature in FEATURES:
        stacked = np.column_stack(
            [ticks[name].to_numpy() for name in feature_names(feature, joints)]
        ).astype(np.float32)
        values[feature] = stacked
        columns[feature] = pa.FixedSizeListArray.from_arrays(
            pa.array(stacked.reshape(-1), type=pa.float32()), stacked.shape[1]
        )
    index_values = {
        "timestamp": ticks["t"].to_numpy().astype(np.float32),
        "frame_index": np.arange(n, dtype=np.int64),
        "episode_index": np.full(n, episode_index, dtype=np.int64),
        "index": np.arange(first, first + n, dtype=np.int64),
        "task_index": np.zeros(n, dtype=np.int64),
    }
    for name, array in index_values.items():
        values[name] = array
        columns[name] = pa.array(array)
    return pa.table(columns), values


def export(dataset: Path, out: Path, layout: LerobotLayout) -> list[str]:
    """Write the dataset at `dataset` in LeRobot's v3.0 layout into `out` (made here, inside
    the release's staging directory); return the files written, relative to `out`."""
    dataset, out = Path(dataset), Path(out)
    robot, joints = dataset_arm(dataset)
    out.mkdir()
    file_frames = layout.file_frames or DATA_FILE_SIZE_IN_MB * 2**20 // frame_bytes(joints)
    writer = Writer(out, max(1, file_frames), layout.chunks_size)
    moments = {name: Moments.empty(spec["shape"][0]) for name, spec in features(joints).items()}
    rows = _episodes(dataset)
    by_id = {row["episode_id"]: row for row in rows}
    index_of = {row["episode_id"]: index for index, row in enumerate(rows)}
    episode_rows: list[dict[str, Any]] = []
    first = 0
    for split in ALL_SPLITS:
        for episode_id, ticks in _split_ticks(dataset, split, joints):
            episode_index = index_of[episode_id]
            if episode_index != len(episode_rows):  # the builder writes both in one order
                raise ValueError(
                    f"episode {episode_id!r}: ticks.parquet and episodes.parquet differ"
                )
            chunk_index, file_index = writer.place(ticks.num_rows)
            frames, values = _frames(ticks, episode_index, first, joints)
            writer.add(frames)
            if split == "train":  # normalisation from train only, as the release's stats.json
                for name, array in values.items():
                    moments[name].add(array)
            row = by_id[episode_id]
            episode_rows.append(
                {
                    "episode_index": episode_index,
                    "tasks": [TASK],
                    "length": ticks.num_rows,
                    "data/chunk_index": chunk_index,
                    "data/file_index": file_index,
                    "dataset_from_index": first,
                    "dataset_to_index": first + ticks.num_rows,
                    "meta/episodes/chunk_index": 0,
                    "meta/episodes/file_index": 0,
                    # gainfarm's own: which episode, trajectory and split, whether calm.
                    "episode_id": episode_id,
                    "trajectory_id": row["trajectory_id"],
                    "split": split,
                    "calm": bool(row.get("calm", True)),
                }
            )
            first += ticks.num_rows
    writer.flush()
    episodes_path = EPISODES_PATH.format(chunk_index=0, file_index=0)
    (out / episodes_path).parent.mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(episode_rows), out / episodes_path)
    write_tasks(out / TASKS_PATH)
    info = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type(robot),
        "total_episodes": len(episode_rows),
        "total_frames": first,
        "total_tasks": 1,
        "chunks_size": layout.chunks_size,
        "data_files_size_in_mb": DATA_FILE_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILE_SIZE_IN_MB,
        "fps": FPS,
        "splits": splits(episode_rows),
        "data_path": DATA_PATH,
        "video_path": None,
        "features": features(joints),
    }
    write_atomically(out / INFO_PATH, (json.dumps(info, indent=4) + "\n").encode())
    stats = {name: moment.as_json() for name, moment in moments.items()}
    write_atomically(
        out / STATS_PATH, (json.dumps(stats, indent=4, allow_nan=False) + "\n").encode()
    )
    return sorted([*writer.written, episodes_path, TASKS_PATH, INFO_PATH, STATS_PATH])


def splits(episode_rows: Sequence[dict[str, Any]]) -> dict[str, str]:
    """Each non-empty split's episode indices as LeRobot writes them, "start:end" (end out)."""
    found = {}
    for split in ALL_SPLITS:
        indices = [row["episode_index"] for row in episode_rows if row["split"] == split]
        if indices:
            found[split] = f"{min(indices)}:{max(indices) + 1}"
    return found


def write_tasks(path: Path) -> None:
    """meta/tasks.parquet as LeRobot writes it with pandas (a frame indexed by the task, with
    its task_index): the index is a column that pandas' metadata names as the index, written
    here by hand, as pandas is not a dependency."""
    pandas = {
        "index_columns": ["task"],
        "column_indexes": [
            {
                "name": None,
                "field_name": None,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }
        ],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": "task",
                "field_name": "task",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    table = pa.table(
        {"task_index": pa.array([0], pa.int64()), "task": pa.array([TASK], pa.string())}
    ).replace_schema_metadata({"pandas": json.dumps(pandas)})
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)
