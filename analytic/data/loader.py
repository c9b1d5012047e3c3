"""Reading a dataset (analytic/data/dataset.py) for learning: one split as NumPy arrays.

    from gainfarm.analytic import load_dataset

    train = load_dataset("datasets/generic", "train")
    x, y = train.inputs(normalised=True), train.targets(normalised=True)  # (n, 3N), (n, N)

N is the dataset's arm's joint count (7 for the iiwa 14, 6 for the UR5e: `train.joint_names`).

Works on any directory `analytic dataset` wrote, a release or not; a release's stats.json gives
the normalisation, computed over its train split only, so nothing of validation or test leaks
into it. Light on purpose: pyarrow and NumPy only, no simulator, no scikit-learn.

`TickDataset` is a map-style dataset (`__len__`, `__getitem__` giving float32 rows), the
protocol PyTorch's DataLoader takes: its default collate turns NumPy arrays into tensors. Nothing
here imports torch; PyTorch's wheels pull gigabytes of CUDA packages, more than this project's
machines and CI install, so the protocol is what is offered and tested.
"""

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from gainfarm.analytic.data.dataset_columns import (
    JOINTS_BEFORE,
    JOINTS_KEY,
    ROBOT_BEFORE,
    ROBOT_KEY,
)

TICKS, EPISODES, STATS_JSON = "ticks.parquet", "episodes.parquet", "stats.json"
# A dataset's parts (the `split` column), for every module that writes or reads one. An episode
# on a plant other than its run's own (a robust run's tuning variants, a rerun's --plants) is in
# its trajectory's part with the VARIANTS suffix: train, validation and test are the runs' own
# plants, so that a model without the plant among its inputs can reach that plant's floor. Mixed,
# the same motion asks for different torques on different plants, a spread no such model can
# learn (docs/dataset.md, "One plant per split").
SPLITS = ("train", "validation", "test")
VARIANTS = "_variants"
VARIANT_SPLITS = tuple(f"{split}{VARIANTS}" for split in SPLITS)
ALL_SPLITS = SPLITS + VARIANT_SPLITS
LOADER_SPLITS = (*SPLITS, "test_calm", *VARIANT_SPLITS)
# DatasetSplit's arrays → their column in ticks.parquet (the joint's suffix _A1.._A7 added, the
# arm's joints'). The
# acceleration and the motor torque are what a model of the arm learns (analytic.data.learning):
# a dataset from before them (version 3, 2) has only the difference and the command.
SIGNALS = {
    "q": ("q",),
    "qd": ("qd",),
    "qdd": ("qdd_sg", "qdd"),
    "u": ("u_motor", "u"),
    "tau": ("tau",),
    "theta": ("theta",),
    "theta_d": ("theta_d",),
    "q_des": ("q_des",),
    "qd_des": ("qd_des",),
}
INPUTS = ("q", "qd", "qdd")  # inverse dynamics: (q, q̇, q̈) → u
TARGETS = ("u",)


@dataclass(frozen=True)
class DatasetSplit:
    """The ticks of one split, in ticks.parquet's order, every row (NaN where the table has
    NaN: `qdd` in an episode shorter than the Savitzky-Golay window). Joint arrays are (n, N),
    one column per joint of the dataset's arm (`joint_names`)."""

    split: str
    robot: str  # the arm (a gainfarm.robots name)
    joint_names: tuple[str, ...]  # its joints: the joint arrays' columns
    columns: dict[str, str]  # each signal → the ticks.parquet column prefix it was read from
    episode_id: np.ndarray  # (n,) str
    t: np.ndarray  # (n,) s since the episode started
    calm: np.ndarray  # (n,) bool: the row's episode is calm
    q: np.ndarray  # rad
    qd: np.ndarray  # rad/s
    qdd: np.ndarray  # rad/s², the qdd_sg column
    u: np.ndarray  # N·m, the u_motor column: what the motors exerted
    tau: np.ndarray  # N·m, the torque sensors
    theta: np.ndarray  # rad, motor side
    theta_d: np.ndarray  # rad/s
    q_des: np.ndarray  # rad
    qd_des: np.ndarray  # rad/s
    stats: dict[str, dict[str, Any]] | None  # stats.json: per column, over train; None if absent

    def __len__(self) -> int:
        return len(self.t)

    def inputs(self, normalised: bool = False) -> np.ndarray:
        """(n, 3N): q, q̇, q̈ side by side, the inputs of an inverse-dynamics model."""
        return self._joined(INPUTS, normalised)

    def targets(self, normalised: bool = False) -> np.ndarray:
        """(n, N): u, the motors' torque, what an inverse-dynamics model predicts."""
        return self._joined(TARGETS, normalised)

    def _joined(self, signals: tuple[str, ...], normalised: bool) -> np.ndarray:
        values = np.hstack([getattr(self, signal) for signal in signals])
        if not normalised:
            return values
        mean, std = self.normalisation(signals)
        return (values - mean) / std

    def normalisation(self, signals: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """The train split's mean and std of `signals`' columns (stats.json); a std of zero (a
        joint that never moved) as 1, so that it is centred, not divided by zero."""
        if self.stats is None:
            raise ValueError(
                "normalised needs stats.json, which only a release has (analytic dataset "
                "--release NAME)"
            )
        names = [f"{self.columns[s]}_{joint}" for s in signals for joint in self.joint_names]
        missing = [name for name in names if name not in self.stats]
        if missing:
            raise ValueError(f"stats.json has no statistics of {missing[0]!r}")
        mean = np.array([_number(self.stats[name]["mean"]) for name in names])
        std = np.array([_number(self.stats[name]["std"]) for name in names])
        return mean, np.where(np.isfinite(std) & (std > 0), std, 1.0)


def _number(value: float | None) -> float:
    return np.nan if value is None else float(value)  # JSON has no NaN: written as null


class TickDataset:
    """A map-style dataset of one split for inverse dynamics: item i is (inputs, target) of
    the i-th row whose inputs and target are all finite, as float32 arrays of 3N and N. Any
    loader that takes `__len__` and `__getitem__` takes it, PyTorch's DataLoader included
    (torch is not imported here: see the module's docstring)."""

    def __init__(self, split: DatasetSplit, normalised: bool = False):
        inputs = split.inputs(normalised)
        targets = split.targets(normalised)
        finite = np.isfinite(inputs).all(axis=1) & np.isfinite(targets).all(axis=1)
        self.rows = np.flatnonzero(finite)  # which rows of `split` the items are
        self.x = np.ascontiguousarray(inputs[finite], dtype=np.float32)
        self.y = np.ascontiguousarray(targets[finite], dtype=np.float32)

    def __len__(self) -> int:
        return len(self.x)

    def __getitem__(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        return self.x[index], self.y[index]


def load_dataset(path: str | Path, split: str = "train") -> DatasetSplit:
    """The rows of `split` (train, validation, test, test_calm: the test rows of calm episodes,
    or train_variants, validation_variants, test_variants) of the dataset at `path`. ValueError
    naming the split if it is not one of them; FileNotFoundError if `path` holds no dataset."""
    if split not in LOADER_SPLITS:
        raise ValueError(f"unknown split {split!r}: one of {', '.join(LOADER_SPLITS)}")
    path = Path(path)
    if not (path / TICKS).is_file():
        raise FileNotFoundError(f"{str(path)!r} holds no dataset (no {TICKS})")
    robot, joints = dataset_arm(path)
    names = set(pq.read_schema(path / TICKS).names)
    columns = {}
    for signal, candidates in SIGNALS.items():
        found = [c for c in candidates if f"{c}_{joints[0]}" in names]
        if not found:
            raise ValueError(f"{str(path)!r}: {TICKS} has no {candidates[0]} columns")
        columns[signal] = found[0]
    wanted = ["episode_id", "t"] + [f"{c}_{j}" for c in columns.values() for j in joints]
    part = "test" if split == "test_calm" else split
    table = pq.read_table(path / TICKS, columns=wanted, filters=[("split", "==", part)])
    episode_id = table["episode_id"].to_numpy(zero_copy_only=False).astype(str)
    rough = _rough_episodes(path)
    calm = ~np.isin(episode_id, sorted(rough))
    if split == "test_calm":
        table = table.filter(
            pc.invert(pc.is_in(table["episode_id"], pa.array(sorted(rough), type=pa.string())))
        )
        episode_id, calm = episode_id[calm], calm[calm]
    arrays = {
        signal: np.column_stack([table[f"{column}_{joint}"].to_numpy() for joint in joints]).astype(
            float
        )
        if table.num_rows
        else np.empty((0, len(joints)))
        for signal, column in columns.items()
    }
    stats_path = path / STATS_JSON
    stats = json.loads(stats_path.read_text(encoding="utf-8")) if stats_path.is_file() else None
    return DatasetSplit(
        split=split,
        robot=robot,
        joint_names=joints,
        columns=columns,
        episode_id=episode_id,
        t=table["t"].to_numpy().astype(float),
        calm=calm,
        stats=stats,
        **arrays,
    )


def dataset_arm(path: str | Path) -> tuple[str, tuple[str, ...]]:
    """The robot a dataset is of and its joints, from ticks.parquet's schema metadata; a dataset
    from before it named them is the iiwa 14's. ValueError, one line, if they are malformed."""
    metadata = pq.read_schema(Path(path) / TICKS).metadata or {}
    if JOINTS_KEY.encode() not in metadata:
        return ROBOT_BEFORE, JOINTS_BEFORE
    robot = metadata.get(ROBOT_KEY.encode(), b"").decode()
    try:
        joints = json.loads(metadata[JOINTS_KEY.encode()])
    except ValueError:
        joints = None
    if not robot or not isinstance(joints, list) or not all(isinstance(j, str) for j in joints):
        raise ValueError(f"{str(path)!r}: {TICKS} names its arm's joints malformed")
    if not joints:
        raise ValueError(f"{str(path)!r}: {TICKS} names an arm of no joints")
    return robot, tuple(joints)


def _rough_episodes(path: Path) -> set[str]:
    """Episodes whose `calm` is false in episodes.parquet; none before the flag (version 4)."""
    if "calm" not in pq.read_schema(path / EPISODES).names:
        return set()
    table = pq.read_table(path / EPISODES, columns=["episode_id", "calm"])
    ids, calm = table["episode_id"].to_pylist(), table["calm"].to_pylist()
    return {str(episode) for episode, ok in zip(ids, calm, strict=True) if not ok}
