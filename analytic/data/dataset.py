"""The dataset for learning the cobot's dynamics: the tuned controllers' episodes, gathered.

From one or more tuning runs, take the selected controllers (the whole Pareto front, or its knee)
and their episodes on each trajectory (optionally each of them once more on further trajectories,
through the farm: the paper's last step), and write a dataset directory:

    episodes/<episode_id>.mcap  the MCAP logs, as the workers wrote them (hard-linked if possible)
    ticks.parquet               one row per 2 ms tick of every episode
    episodes.parquet            one row per episode: gains, objectives, trajectory, model, split
    trajectories.parquet        one row per distinct trajectory: its identity and its split
    README.md                   the dataset card

Episode ids derive from the run's random run_id (run.json), never from its directory's name, so
two runs in directories of one name cannot overwrite each other; an id that would still repeat
(the same run given twice, or a copy of a run) is refused. The split into train, validation and
test is by trajectory, so no trajectory is seen in training and again in testing.

Clean by construction: a controller that breaks its run's safety limits (schemas.limits) on any
of its episodes, the rerun's included, is left out with all its episodes unless `infeasible` asks
for it (a run's front holds none, but a run from before the limits may, and a rerun trajectory or
plant may find one); and an episode that is not calm (its command chatters, or it diverged) is
left out unless `include_rough` asks for it. Each episode's row carries its measures, whether
they are within the limits and whether it is calm: data a rigid-body model cannot explain (a
chattering elastic joint) would otherwise dominate every score learned on it.

The directory appears whole or not at all: it is built beside its destination and renamed.
"""

import contextlib
import dataclasses
import hashlib
import json
import math
import os
import shutil
import textwrap
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import TypeAdapter, ValidationError
from scipy.signal import savgol_filter

from gainfarm.analytic.compose import new_study_name
from gainfarm.analytic.data.loader import SPLITS, VARIANTS
from gainfarm.analytic.evaluators.batch import batch_jobs, run_batch
from gainfarm.analytic.evaluators.evaluator import EpisodeStatus, Evaluator
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.tuning.picks import knee
from gainfarm.analytic.tuning.records import (
    RUN_JSON,
    FrontMember,
    RunRecord,
    read_identity,
    read_run,
)
from gainfarm.analytic.tuning.run import RunBusy, TuningRun, upgrade
from gainfarm.cli.words import counted
from gainfarm.edges.files import staging_directory, write_atomically
from gainfarm.plugins import OBJECTIVES, load_plugins
from gainfarm.schemas.documents import quoted
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.limits import MEASURES, Limits
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, read_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import JOINT_NAMES, ModelSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD, TrajectorySpec
from gainfarm.schemas.wire import describe, one_line
from gainfarm.worker.episode import motor_torque

Selection = Literal["front", "knee"]
Split = tuple[float, float, float]

# 2: run-id episode ids, trajectories.parquet, qdd, split, units; 3: u_motor; 4: qdd_sg, calm;
# 5: the *_variants splits
DATASET_VERSION = "5"
DEFAULT_SPLIT: Split = (0.6, 0.2, 0.2)
RUN_ID_DIGITS = 8  # of the run's 32: unique enough, and a collision is refused, not merged
TRAJECTORY_ID_DIGITS = 12
TUNING, RERUN = "tuning", "rerun"  # the `source` column: where an episode comes from
RERUN_DIR = "rerun"  # the rerun's batch directory, inside the staging directory

# qdd_sg: the second derivative of a Savitzky-Golay fit of q, a cubic over SG_WINDOW ticks
# (42 ms) centred on each tick, within the episode. The forward difference of q̇ (itself a
# 3-tick difference of quantised, noisy angles) leaves the true model of the realistic plant a
# test nMSE of 0.093; this fit, 0.0011. Measured on 51 test episodes of a tuned front on the
# FRI plant: windows 11, 21, 31, 51 gave 0.0031, 0.0011, 0.0016, 0.0059 with a cubic, and a
# quintic did no better under 51 ticks (docs/dataset.md, "Two accelerations").
SG_WINDOW = 21
SG_ORDER = 3
# An episode is calm if it ran to its end and its command keeps out of the band above the arm's
# lowest elastic mode: the chatter measure (schemas.objectives) within the default safety
# limit's 2 % of the torque limit. The smooth controllers measured put at most 0.8 % there, the
# chattering ones 50 % to 99 % (schemas.limits).
CALM_CHATTER = Limits().chatter
EXCITATION_DURATION = 10.0  # s, each of `--excitations`: 5,000 ticks

# Per-tick signals: name → (unit, what it is). Joint signals get _A1.._A7, Cartesian _x.._z.
JOINT_SIGNALS = {
    "q": ("rad", "link-side joint position, as the encoders measured it"),
    "qd": ("rad/s", "link-side joint velocity, as measured"),
    "qdd": (
        "rad/s^2",
        "link-side acceleration (qd[k+1] - qd[k]) / control period, within the episode: what "
        "row k's command produced; NaN on an episode's last tick",
    ),
    "qdd_sg": (
        "rad/s^2",
        f"link-side acceleration at tick k: second derivative of a Savitzky-Golay fit of q "
        f"(order {SG_ORDER}, {SG_WINDOW} ticks centred on k), within the episode; NaN in an "
        f"episode shorter than {SG_WINDOW} ticks",
    ),
    "tau": ("N*m", "joint torque sensors' reading (the spring torque if the joints are elastic)"),
    "u": (
        "N*m",
        "the controller's torque command as the robot applied it (delayed, saturated) from tick "
        "k to k + 1; behind FRI without the robot's own gravity compensation",
    ),
    "u_motor": (
        "N*m",
        "torque the motors exerted from tick k to k + 1: u, plus behind FRI the robot's gravity "
        "model at its measured angles, saturated; what a model of the arm's dynamics predicts",
    ),
    "theta": ("rad", "motor-side angle, as measured (the link angle if the joints are rigid)"),
    "theta_d": ("rad/s", "motor-side velocity, as measured"),
    "q_des": ("rad", "reference joint position"),
    "qd_des": ("rad/s", "reference joint velocity"),
}
LOGGED_JOINT_SIGNALS = tuple(s for s in JOINT_SIGNALS if s not in ("qdd", "qdd_sg", "u_motor"))
CARTESIAN_SIGNALS = {
    "ee": ("m", "flange position, base frame"),
    "ee_des": ("m", "desired flange position, base frame"),
}
AXES = ("x", "y", "z")

# Every other column of the three tables: name → (unit, what it is). "" is no unit (ids, counts).
COLUMNS = {
    "episode_id": ("", "<first 8 hex digits of the run_id>-<job id> (-rerun- for reruns)"),
    "trajectory": ("", "the trajectory's kind"),
    "trajectory_id": ("", "short SHA-256 of the trajectory's canonical JSON spec"),
    "split": ("", "train, validation or test: by trajectory"),
    "t": ("s", "time since the episode started"),
    "run": ("", "the tuning run's directory name, or 'rerun'"),
    "run_id": ("", "the run_id (run.json) of the run the controller was tuned in"),
    "source": ("", "tuning: an episode of the tuning run; rerun: run again for the dataset"),
    "f_acc": ("m", "mean end-effector position error of this episode"),
    "f_t": ("(N*m)^2", "mean squared torque change per tick of this episode"),
    "diverged": ("", "the episode was stopped early"),
    "ticks": ("", "ticks in the episode"),
    "duration": ("s", "the trajectory's duration"),
    "trajectory_spec": ("", "the TrajectorySpec, JSON"),
    "model": ("", "the plant: ModelSpec, JSON"),
    "gravity_compensation": ("", "g(q_des) feed-forward was on"),
    "feedforward": ("", "SHA-256 of the learned inverse-dynamics feed-forward, if any"),
    "candidate_f_acc": ("m", "the controller's f_acc over its run's trajectory set"),
    "candidate_f_t": ("(N*m)^2", "the controller's f_t over its run's trajectory set"),
    "torque_step": ("1", "largest torque change in a tick, share of the joint's torque limit"),
    "saturated_fraction": ("1", "share of ticks with a joint at its torque limit"),
    "speed": ("1", "largest measured joint speed, share of its data-sheet limit"),
    "chatter": ("1", "RMS of the command above 10 Hz, share of the joint's torque limit"),
    "lag": ("rad", "largest RMS of a joint's measured angle less its reference's"),
    "within_limits": ("", "the controller keeps its run's safety limits on all its episodes"),
    "calm": ("", "the episode ran to its end without chatter (chatter within 0.02)"),
    "kind": ("", "the trajectory's kind"),
    "seed": ("", "which path of its kind (random, fourier; spiral, pyramid turned and mirrored)"),
    "center_x": ("m", "the Cartesian path's centre, base frame"),
    "center_y": ("m", "the Cartesian path's centre, base frame"),
    "center_z": ("m", "the Cartesian path's centre, base frame"),
    "size": ("m", "the Cartesian path's half-width"),
    "twist": ("rad", "amplitude of the flange's turn about the tool axis"),
    "turns": ("", "spiral only: turns"),
    "waypoints": ("", "random only: control points"),
    "harmonics": ("", "fourier only: harmonics per joint"),
    "spec": ("", "the TrajectorySpec, canonical JSON (sorted keys): what trajectory_id hashes"),
    "episodes": ("", "episodes of this trajectory in the dataset"),
}
for _joint in JOINT_NAMES:
    COLUMNS[f"kp_{_joint}"] = ("N*m/rad", "proportional gain")
    COLUMNS[f"kd_{_joint}"] = ("N*m*s/rad", "derivative gain")


class NoEpisodes(ValueError):
    pass


class UnreadableRun(ValueError):
    pass


class DuplicateEpisodes(ValueError):
    """Two sources would give the same episode id: refused, never merged."""


class BadSplit(ValueError):
    """The split's fractions, or too few trajectories for its non-empty parts."""


class BadRerun(ValueError):
    """A rerun trajectory list that is not one, or a trajectory the robot cannot follow."""


class RerunFailed(ValueError):
    """A rerun episode did not run: the dataset would be missing it."""


# Given the directory a rerun's batch writes into, a context giving the evaluator to run it on.
RerunFarm = Callable[[Path], AbstractContextManager[Evaluator]]


@dataclass(frozen=True)
class ChosenRun:
    """One run and the controllers selected from it."""

    directory: Path
    name: str
    run_id: str
    model: ModelSpec
    members: list[FrontMember]
    feedforward: str | None = None  # the learned model its episodes add to the PD, if any
    # The safety limits its config checks every episode against.
    limits: Limits = dataclasses.field(default_factory=Limits)


@dataclass(frozen=True)
class EpisodeSource:
    """One episode going into the dataset."""

    episode_id: str
    run: str  # the run directory's name, or RERUN
    run_id: str  # the run the controller comes from
    path: Path
    member: FrontMember
    source: str = TUNING


@dataclass(frozen=True)
class Episode:
    """One episode read: its ticks (all but the split, assigned once every trajectory is known)
    and its row of episodes.parquet."""

    source: EpisodeSource
    trajectory: TrajectorySpec
    ticks: pa.Table
    row: dict[str, object]


def select(run: RunRecord, selection: Selection) -> list[FrontMember]:
    """The front, or its knee: the member `analytic export` takes (analytic.tuning.picks)."""
    front = run.front
    if selection == "front" or not front:
        return front
    return [knee(front)]


def run_id_of(run_dir: Path) -> str:
    """The run's id from run.json. A run from between front.json and run ids has none yet:
    opening it gives it one (what its next resume would do); one that another process is
    running got it when that process opened it."""
    path = Path(run_dir) / RUN_JSON
    if not path.exists():
        with contextlib.suppress(RunBusy):
            TuningRun.open(run_dir).close()
    return read_identity(path).run_id


def choose(run_dirs: Sequence[Path], selection: Selection) -> list[ChosenRun]:
    """Each run with its selected controllers; a run given twice (or a copy of one: the same
    run_id) is refused, since its episodes would get the same ids."""
    chosen: list[ChosenRun] = []
    seen: dict[str, Path] = {}
    for run_dir in run_dirs:
        try:
            upgrade(run_dir)
            run = read_run(run_dir)
            run_id = run_id_of(run_dir)
        except (OSError, ValueError, RunBusy) as error:
            raise UnreadableRun(f"{str(run_dir)!r}: unreadable run ({one_line(error)})") from None
        if run_id in seen:
            raise DuplicateEpisodes(
                f"{str(seen[run_id])!r} and {str(run_dir)!r} are the same run (run_id {run_id}): "
                "a run given twice, or a copy of one; give each run once"
            )
        seen[run_id] = Path(run_dir)
        name = Path(run_dir).resolve().name
        members = select(run, selection)
        chosen.append(
            ChosenRun(
                Path(run_dir),
                name,
                run_id,
                run.config.model,
                members,
                run.config.feedforward,
                run.config.limits,
            )
        )
    return chosen


def sources(chosen: Sequence[ChosenRun]) -> list[EpisodeSource]:
    """Every kept log of the selected members, as each run's front.json lists them."""
    found = []
    for run in chosen:
        inside = run.directory.resolve()
        for member in run.members:
            for log in member.logs:
                path = run.directory / log
                if not path.resolve().is_relative_to(inside):
                    # front.json is the run's word, not the farm's: a log named from outside the
                    # run (../, an absolute path, a symlink out) is never read nor linked in.
                    raise UnreadableRun(
                        f"{str(run.directory)!r}: front.json names the log {quoted(str(log))}, "
                        "which lies outside the run: refused"
                    )
                if path.is_file():
                    episode_id = f"{run.run_id[:RUN_ID_DIGITS]}-{path.stem}"
                    found.append(EpisodeSource(episode_id, run.name, run.run_id, path, member))
    return found


def refuse_duplicates(episode_ids: Sequence[str]) -> None:
    """Two episodes under one id would overwrite each other's log: refuse instead."""
    repeated = sorted(name for name, count in Counter(episode_ids).items() if count > 1)
    if repeated:
        raise DuplicateEpisodes(
            f"episode id {repeated[0]!r} would be given to {Counter(episode_ids)[repeated[0]]} "
            f"episodes ({len(repeated)} ids repeat): two runs share a run_id prefix; give each "
            "run once"
        )


def canonical_json(trajectory: TrajectorySpec) -> str:
    """The spec's JSON with sorted keys and no spaces: equal specs, equal text."""
    return json.dumps(trajectory.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))


def trajectory_id(trajectory: TrajectorySpec) -> str:
    return hashlib.sha256(canonical_json(trajectory).encode()).hexdigest()[:TRAJECTORY_ID_DIGITS]


def check_split(fractions: Sequence[float]) -> Split:
    """Three non-negative fractions summing to 1 (train, validation, test)."""
    values = tuple(float(value) for value in fractions)
    if (
        len(values) != 3
        or not all(math.isfinite(value) and value >= 0 for value in values)
        or not math.isclose(sum(values), 1.0, abs_tol=1e-9)
    ):
        shown = ",".join(f"{value:g}" for value in values)
        raise BadSplit(
            f"expected three non-negative fractions (train,validation,test) summing to 1, "
            f"got {shown}"
        )
    return values  # type: ignore[return-value]  # three, checked above


def split_counts(fractions: Split, trajectories: int) -> list[int]:
    """How many trajectories each part gets: the largest-remainder rounding of its share, then
    every part with a positive fraction at least one, taken from the largest part."""
    fractions = check_split(fractions)
    positive = [index for index, value in enumerate(fractions) if value > 0]
    if len(positive) > trajectories:
        names = "/".join(SPLITS[index] for index in positive)
        example = "1,0,0" if trajectories <= 1 else "0.5,0,0.5"
        raise BadSplit(
            f"{len(positive)} non-empty parts ({names}) but the dataset has only {trajectories} "
            f"trajector{'y' if trajectories == 1 else 'ies'}: give the empty parts 0 "
            f"(e.g. {example}), or add trajectories with --rerun"
        )
    total = sum(fractions)
    exact = [value / total * trajectories for value in fractions]
    counts = [math.floor(value) for value in exact]
    leftover = trajectories - sum(counts)
    by_remainder = sorted(positive, key=lambda index: (counts[index] - exact[index], index))
    for index in by_remainder[:leftover]:
        counts[index] += 1
    for index in positive:
        if counts[index] == 0:  # some other part has two or more: there are enough trajectories
            donor = max(range(3), key=lambda other: (counts[other], -other))
            counts[donor] -= 1
            counts[index] += 1
    return counts


def assign_splits(ids: Sequence[str], fractions: Split, seed: int = 0) -> dict[str, str]:
    """trajectory_id → split. Deterministic: the ids in the order of their hash with `seed`,
    cut by `split_counts`; so the split does not depend on the order the runs were given in."""
    unique = sorted(set(ids))
    counts = split_counts(fractions, len(unique))
    order = sorted(unique, key=lambda tid: hashlib.sha256(f"{seed}:{tid}".encode()).hexdigest())
    names = [name for name, count in zip(SPLITS, counts, strict=True) for _ in range(count)]
    return dict(zip(order, names, strict=True))


def read_rerun(path: Path) -> list[TrajectorySpec]:
    """The rerun file: a JSON list of TrajectorySpec objects; BadRerun saying what is wrong."""
    try:
        content = Path(path).read_bytes()
    except OSError as error:
        raise BadRerun(f"cannot read {str(path)!r}: {error.strerror}") from None
    try:
        trajectories = TypeAdapter(list[TrajectorySpec]).validate_json(content)
    except ValidationError as error:
        raise BadRerun(f"{str(path)!r}: {describe(error)}") from None
    check_rerun(trajectories, followable=False)
    return trajectories


def excitations(count: int, duration: float = EXCITATION_DURATION) -> list[TrajectorySpec]:
    """`count` fourier excitations (seeds 0 to count - 1): band-limited joint motions over the
    whole workspace, the identification literature's choice, each feasible by construction
    (worker.reference); what `--excitations` adds to the rerun."""
    return [TrajectorySpec(kind="fourier", seed=seed, duration=duration) for seed in range(count)]


def check_rerun(trajectories: Sequence[TrajectorySpec], followable: bool = True) -> None:
    """A non-empty list without repeats (a repeat would be the same episode twice), and, with
    `followable`, only trajectories the iiwa can follow (every episode of another would fail)."""
    if not trajectories:
        raise BadRerun("the list of trajectories is empty")
    first: dict[str, int] = {}
    for number, trajectory in enumerate(trajectories, start=1):
        earlier = first.setdefault(canonical_json(trajectory), number)
        if earlier != number:
            raise BadRerun(f"trajectory {number} repeats trajectory {earlier}")
    if not followable:
        return
    from gainfarm.worker.ik import UnreachablePath  # MuJoCo loads only when a rerun needs it
    from gainfarm.worker.reference import InfeasibleReference, reference_for

    for number, trajectory in enumerate(trajectories, start=1):
        try:
            reference_for(trajectory)
        except (InfeasibleReference, UnreachablePath) as error:
            what = f"{trajectory.kind}, {trajectory.duration:g} s"
            raise BadRerun(f"trajectory {number} ({what}): {error}") from None


def tick_columns(episode_id: str, log: EpisodeLog) -> dict[str, np.ndarray]:
    """The ticks of one episode as flat, named columns (t, q_A1 ... ee_des_z), the split aside.

    qdd is differenced within the episode, forward: row k's u acts from tick k to k + 1, so
    (qd[k+1] - qd[k]) / period is the acceleration it produced. The last tick has no next one:
    NaN, never a difference across two episodes. u_motor is what the motors exerted
    (worker.episode.motor_torque): u itself, or behind FRI u and the robot's gravity model.
    """
    ticks = log.ticks
    columns: dict[str, np.ndarray] = {
        "episode_id": np.full(ticks, episode_id, dtype=object),
        "trajectory": np.full(ticks, log.metadata.spec.trajectory.kind, dtype=object),
        "trajectory_id": np.full(ticks, trajectory_id(log.metadata.spec.trajectory), dtype=object),
        "t": log.t,
    }
    qdd = np.full_like(log.qd, np.nan, dtype=np.float64)
    qdd[:-1] = np.diff(log.qd, axis=0) / log.metadata.control_period
    signals = {signal: getattr(log, signal) for signal in LOGGED_JOINT_SIGNALS}
    signals |= {
        "qdd": qdd,
        "qdd_sg": smoothed_acceleration(log.q, log.metadata.control_period),
        "u_motor": motor_torque(log),
    }
    for signal in JOINT_SIGNALS:
        for index, joint in enumerate(JOINT_NAMES):
            columns[f"{signal}_{joint}"] = signals[signal][:, index]
    for signal in CARTESIAN_SIGNALS:
        values = getattr(log, signal)
        for index, axis in enumerate(AXES):
            columns[f"{signal}_{axis}"] = values[:, index]
    return columns


def smoothed_acceleration(q: np.ndarray, period: float) -> np.ndarray:
    """q̈ of one episode's (n, 7) angles: the Savitzky-Golay fit's second derivative (SG_WINDOW,
    SG_ORDER), the window's edges fitted by one polynomial ("interp"); NaN if the episode is
    shorter than the window."""
    if len(q) < SG_WINDOW:
        return np.full(np.shape(q), np.nan)
    return savgol_filter(q, SG_WINDOW, SG_ORDER, deriv=2, delta=period, axis=0, mode="interp")


def plant_of(episode: Episode) -> ModelSpec:
    return ModelSpec.model_validate_json(str(episode.row["model"]))


def is_calm(chatter: float, diverged: bool) -> bool:
    """The episode ran to its end and its command does not chatter (CALM_CHATTER)."""
    return not diverged and math.isfinite(chatter) and chatter <= CALM_CHATTER


def episode_row(source: EpisodeSource, log: EpisodeLog) -> dict[str, object]:
    spec = log.metadata.spec
    scores = score(log, load_plugins(OBJECTIVES, spec.objectives))  # a run's plug-in's too
    row: dict[str, object] = {
        "episode_id": source.episode_id,
        "run": source.run,
        "run_id": source.run_id,
        "source": source.source,
        "trajectory_id": trajectory_id(spec.trajectory),
    }
    row |= {f"kp_{joint}": gain for joint, gain in zip(JOINT_NAMES, spec.gains.kp, strict=True)}
    row |= {f"kd_{joint}": gain for joint, gain in zip(JOINT_NAMES, spec.gains.kd, strict=True)}
    row |= {
        "f_acc": scores.f_acc,
        "f_t": scores.f_t,
        "diverged": scores.diverged,
        "ticks": log.ticks,
        "trajectory": spec.trajectory.kind,
        "duration": spec.trajectory.duration,
        "trajectory_spec": spec.trajectory.model_dump_json(),
        "model": spec.model.model_dump_json(),
        "gravity_compensation": spec.gravity_compensation,
        "feedforward": spec.feedforward or "",
        # NaN where the run did not tune on it (a run on f_t_joint has no candidate f_t)
        "candidate_f_acc": source.member.named.get("f_acc", math.nan),
        "candidate_f_t": source.member.named.get("f_t", math.nan),
    }
    row |= {name: float(getattr(scores, name)) for name in MEASURES}
    row["calm"] = is_calm(float(scores.chatter), bool(scores.diverged))
    return row


def trajectory_row(trajectory: TrajectorySpec) -> dict[str, object]:
    return {
        "trajectory_id": trajectory_id(trajectory),
        "kind": trajectory.kind,
        "seed": trajectory.seed,
        "center_x": trajectory.center[0],
        "center_y": trajectory.center[1],
        "center_z": trajectory.center[2],
        "size": trajectory.size,
        "duration": trajectory.duration,
        "twist": trajectory.twist,
        "turns": trajectory.turns,
        "waypoints": trajectory.waypoints,
        "harmonics": trajectory.harmonics,
        "spec": canonical_json(trajectory),
    }


def read_source(source: EpisodeSource) -> Episode:
    """One episode's log, read and tabled; a damaged log is the run's problem, in one line."""
    try:
        log = read_episode(source.path)
    except NotAnEpisodeLog as error:
        raise UnreadableRun(str(error)) from None
    if log.ticks == 0:  # an episode keeps at least its first tick: the arm starts on its path
        raise UnreadableRun(f"{source.path}: an episode log without a single tick: damaged")
    if log.metadata.control_period != CONTROL_PERIOD:  # qdd and the schema assume one period
        raise UnreadableRun(
            f"{source.path}: control period {log.metadata.control_period} s, "
            f"not the dataset's {CONTROL_PERIOD} s"
        )
    trajectory = log.metadata.spec.trajectory
    ticks = pa.table(tick_columns(source.episode_id, log))
    return Episode(source, trajectory, ticks, episode_row(source, log))


def column_unit(name: str) -> tuple[str, str]:
    """A column's (unit, description); KeyError for a column nobody documented."""
    if name in COLUMNS:
        return COLUMNS[name]
    signal, _, part = name.rpartition("_")
    if part in JOINT_NAMES and signal in JOINT_SIGNALS:
        return JOINT_SIGNALS[signal]
    if part in AXES and signal in CARTESIAN_SIGNALS:
        return CARTESIAN_SIGNALS[signal]
    raise KeyError(f"column {name!r} has no unit")


def with_units(table: pa.Table, metadata: dict[str, str]) -> pa.Table:
    """`table` with every field's unit and description in its metadata, and `metadata` (the
    control period, the dataset's version, ...) in the schema's: Parquet keeps both."""
    fields = []
    for field in table.schema:
        unit, description = column_unit(field.name)
        fields.append(field.with_metadata({"unit": unit, "description": description}))
    schema = pa.schema(fields, metadata=metadata)
    return pa.Table.from_arrays(table.columns, schema=schema)


def link_or_copy(source: Path, target: Path) -> bool:
    """Hard-link `source` at `target` (no second copy of gigabytes of logs; the runs write
    their logs atomically, by rename, so the shared inode is never changed in place); copy it
    if the file system will not (another device, no permission). True if linked."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)
        return False
    return True


@contextlib.contextmanager
def local_rerun_farm(run_dir: Path, workers: int | None = None) -> Iterator[Evaluator]:
    """A local farm for the rerun, for the block: what `build` uses if given none."""
    with (
        local_farm(workers) as endpoint,
        FarmClient([endpoint], new_study_name(run_dir), run_dir) as farm,
    ):
        yield farm


Owner = tuple[ChosenRun, FrontMember, str]  # a rerun job's run, controller and episode id


def plant_variants(nominal: ModelSpec, count: int, seed: int) -> tuple[ModelSpec, ...]:
    """`count` plants around `nominal`, drawn from the shipped uncertainty ranges
    (models/uncertainty.toml) on the held-out stream: never the plants a robust run tuned on."""
    if count == 0:
        return ()
    from gainfarm.analytic.tuning.plants import HELD_OUT, variants

    return variants(nominal, count, seed, stream=HELD_OUT)


def rerun_jobs(
    chosen: Sequence[ChosenRun],
    trajectories: Sequence[TrajectorySpec],
    plants: int = 0,
    seed: int = 0,
) -> tuple[dict[str, EpisodeSpec], dict[str, Owner]]:
    """Every selected controller on every trajectory, on its run's plant and on `plants`
    variants of it (`plant_variants` with `seed`): job id → spec, and job id → its owner. The
    nominal plant's episodes are `<run>-rerun-<job>`, the variants' `<run>-rerun-p<k>-<job>`."""
    jobs: dict[str, EpisodeSpec] = {}
    owners: dict[str, Owner] = {}
    if not trajectories:
        return jobs, owners
    for run in chosen:
        prefix = run.run_id[:RUN_ID_DIGITS]
        gains = [member.gains for member in run.members]
        # batch_jobs orders its jobs candidate by candidate, trajectory by trajectory.
        members = [member for member in run.members for _ in trajectories]
        models = (run.model, *plant_variants(run.model, plants, seed))
        for index, model in enumerate(models):
            variant = f"p{index}-" if index else ""
            specs = batch_jobs(gains, trajectories, model)
            for (job_id, spec), member in zip(specs.items(), members, strict=True):
                key = f"{prefix}-{variant}{job_id}"
                jobs[key] = spec
                owners[key] = (run, member, f"{prefix}-{RERUN}-{variant}{job_id}")
    return jobs, owners


def rerun(
    jobs: dict[str, EpisodeSpec],
    owners: dict[str, Owner],
    staging: Path,
    farm: RerunFarm,
) -> list[Episode]:
    """Run the rerun's jobs (`rerun_jobs`) through the farm, in a batch directory inside the
    staging directory; move each log into episodes/. RerunFailed if any episode could not run:
    the dataset would be silently short of it."""
    if not jobs:
        return []
    batch_dir = staging / RERUN_DIR
    batch_dir.mkdir()
    with farm(batch_dir) as evaluator:
        evaluations = {e.job_id: e for e in run_batch(evaluator, jobs, batch_dir)}
    episodes = []
    for job_id in jobs:
        evaluation = evaluations.get(job_id)
        if (
            evaluation is None
            or evaluation.log is None
            or evaluation.status
            not in (
                EpisodeStatus.ok,
                EpisodeStatus.diverged,
            )
        ):
            status = evaluation.status.value if evaluation else "lost"
            reason = f": {evaluation.reason}" if evaluation and evaluation.reason else ""
            raise RerunFailed(f"rerun episode {job_id} {status}{reason}; nothing was written")
        run, member, episode_id = owners[job_id]
        path = staging / "episodes" / f"{episode_id}.mcap"
        os.replace(evaluation.log, path)
        episodes.append(
            read_source(EpisodeSource(episode_id, RERUN, run.run_id, path, member, RERUN))
        )
    shutil.rmtree(batch_dir)  # its evaluations.json says nothing episodes.parquet does not
    return episodes


def build(
    run_dirs: Sequence[Path],
    out: Path,
    selection: Selection = "front",
    *,
    split: Sequence[float] = DEFAULT_SPLIT,
    split_seed: int = 0,
    rerun_trajectories: Sequence[TrajectorySpec] = (),
    farm: RerunFarm = local_rerun_farm,
    infeasible: bool = False,
    include_rough: bool = False,
    rerun_plants: int = 0,
    finish: Callable[[Path, dict[str, int]], None] | None = None,
) -> dict[str, int]:
    """Write the dataset to `out` (which must not exist); return its counts.

    Everything that can be refused is, before anything is written or run: the runs, repeated
    ids, the rerun's trajectories, the split. The rerun (if any) runs on `farm` last, on each
    run's plant and `rerun_plants` variants of it (`plant_variants`). `finish`,
    if given, is called with the staged directory (complete, card included) and the counts
    before it is renamed into place: what it adds (a release) appears with the dataset or not
    at all, and if it raises, nothing does.
    """
    out = Path(out)
    if out.exists():
        raise FileExistsError(f"{out} already exists")
    fractions = check_split(split)
    chosen = choose(run_dirs, selection)
    found = sources(chosen)
    if rerun_trajectories:
        check_rerun(rerun_trajectories)
        learned = [run.name for run in chosen if run.feedforward is not None]
        if learned:  # run without its model, its controller would make other data: refuse
            raise BadRerun(
                f"run {learned[0]!r} tunes its PD on top of a learned feed-forward; rerunning "
                "such controllers is not supported yet"
            )
    jobs, owners = rerun_jobs(chosen, rerun_trajectories, rerun_plants, split_seed)
    reruns = len(jobs)
    if not found and not reruns:
        raise NoEpisodes(
            "none of the selected controllers has an episode log in its run's episodes/"
        )
    rerun_ids = [episode_id for _, _, episode_id in owners.values()]
    refuse_duplicates([source.episode_id for source in found] + rerun_ids)
    episodes = [read_source(source) for source in found]
    # The split is checked against every trajectory, the rerun's too, before the farm runs.
    known = [episode.trajectory for episode in episodes] + list(rerun_trajectories) * bool(reruns)
    assign_splits([trajectory_id(trajectory) for trajectory in known], fractions, split_seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = staging_directory(out)
    try:
        (staging / "episodes").mkdir()
        linked = sum(
            link_or_copy(e.source.path, staging / "episodes" / f"{e.source.episode_id}.mcap")
            for e in episodes
        )
        copied = len(episodes) - linked
        started = time.perf_counter()
        if jobs:
            episodes += rerun(jobs, owners, staging, farm)
        rerun_seconds = time.perf_counter() - started
        episodes, left_out = within_limits(episodes, chosen, staging / "episodes", infeasible)
        if not episodes:
            raise NoEpisodes(
                f"every selected controller breaks its run's safety limits ({left_out} episodes "
                "left out); --infeasible keeps them"
            )
        episodes, rough = calm_only(episodes, staging / "episodes", include_rough)
        if not episodes:
            raise NoEpisodes(
                f"every episode chatters or diverged ({rough} left out); --include-rough keeps them"
            )
        trajectories = {trajectory_id(e.trajectory): e.trajectory for e in episodes}
        splits = assign_splits(list(trajectories), fractions, split_seed)
        own = {run.run_id: run.model for run in chosen}
        parts = {
            e.source.episode_id: splits[trajectory_id(e.trajectory)]
            + VARIANTS * (plant_of(e) != own[e.source.run_id])
            for e in episodes
        }
        metadata = {
            "dataset_version": DATASET_VERSION,
            "control_period": repr(CONTROL_PERIOD),
            "control_period_unit": "s",
            "split": ",".join(repr(value) for value in fractions),
            "split_seed": str(split_seed),
        }
        ticks = pa.concat_tables(
            episode.ticks.add_column(
                episode.ticks.schema.get_field_index("t"),
                "split",
                pa.array([parts[episode.source.episode_id]] * episode.ticks.num_rows),
            )
            for episode in episodes
        )
        pq.write_table(
            with_units(ticks, metadata | {"table": "ticks"}),
            staging / "ticks.parquet",
            compression="zstd",
        )
        rows = [episode.row | {"split": parts[episode.source.episode_id]} for episode in episodes]
        pq.write_table(
            with_units(pa.Table.from_pylist(rows), metadata | {"table": "episodes"}),
            staging / "episodes.parquet",
        )
        per_trajectory = Counter(str(row["trajectory_id"]) for row in rows)
        trajectory_rows = [
            trajectory_row(trajectory) | {"split": splits[tid], "episodes": per_trajectory[tid]}
            for tid, trajectory in sorted(trajectories.items())
        ]
        pq.write_table(
            with_units(pa.Table.from_pylist(trajectory_rows), metadata | {"table": "trajectories"}),
            staging / "trajectories.parquet",
        )
        counts = {
            "episodes": len(rows),
            "ticks": ticks.num_rows,
            "controllers": len({e.source.member.gains for e in episodes}),
            "runs": len({e.source.run_id for e in episodes}),
            "trajectories": len(trajectories),
            "rerun": sum(e.source.source == RERUN for e in episodes),
            "rerun_trajectories": len(rerun_trajectories),
            "rerun_plants": rerun_plants,
            "rerun_seconds": round(rerun_seconds),
            "linked": linked,
            "copied": copied,
            "infeasible_left_out": left_out,
            "rough_left_out": rough,
            "rough": sum(not e.row["calm"] for e in episodes),
            "on_variants": sum(part.endswith(VARIANTS) for part in parts.values()),
        } | {name: sum(s == name for s in splits.values()) for name in SPLITS}
        text = card(counts, chosen, selection, fractions, split_seed)
        write_atomically(staging / "README.md", text.encode())
        if finish is not None:
            finish(staging, counts)
        staging.rename(out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return counts


def within_limits(
    episodes: list[Episode], chosen: Sequence[ChosenRun], staged: Path, keep: bool
) -> tuple[list[Episode], int]:
    """Mark each episode's row with whether its controller keeps its run's limits on every
    episode it has here; unless `keep`, leave out (and unstage) the episodes of those that do
    not. Returns the episodes and how many were left out."""
    limits = {run.run_id: run.limits for run in chosen}

    def owner(episode: Episode) -> tuple[str, object]:
        return episode.source.run_id, episode.source.member.gains

    broken = {
        owner(episode)
        for episode in episodes
        if limits[episode.source.run_id].violated([episode.row[name] for name in MEASURES])
    }
    for episode in episodes:
        episode.row["within_limits"] = owner(episode) not in broken
    if keep:
        return episodes, 0
    kept = [episode for episode in episodes if owner(episode) not in broken]
    for episode in episodes:
        if owner(episode) in broken:
            (staged / f"{episode.source.episode_id}.mcap").unlink(missing_ok=True)
    return kept, len(episodes) - len(kept)


def _paragraph(text: str) -> str:
    """`text` wrapped as the card's other paragraphs are, at 96 columns."""
    return textwrap.fill(text, width=96, break_long_words=False, break_on_hyphens=False)


def calm_only(episodes: list[Episode], staged: Path, keep: bool) -> tuple[list[Episode], int]:
    """Unless `keep`, leave out (and unstage) the episodes that are not calm (`is_calm`).
    Returns the episodes and how many were left out."""
    if keep:
        return episodes, 0
    kept = [episode for episode in episodes if episode.row["calm"]]
    for episode in episodes:
        if not episode.row["calm"]:
            (staged / f"{episode.source.episode_id}.mcap").unlink(missing_ok=True)
    return kept, len(episodes) - len(kept)


def interface_text(model: ModelSpec) -> str:
    """What the card says of a run's torque interface: how its `u` became `u_motor`."""
    if model.interface == "fri":
        return (
            "behind KUKA's FRI torque interface (the robot added its gravity model of the "
            f"{model.inertials} inertials to `u`: `u_motor` is the sum)"
        )
    return "on a plain torque interface (`u_motor` is `u`)"


def card(
    counts: dict[str, int],
    chosen: Sequence[ChosenRun],
    selection: Selection,
    split: Split = DEFAULT_SPLIT,
    split_seed: int = 0,
) -> str:
    """The dataset's README.md: what it holds, every column and its unit, how it was made."""
    joint_columns = "\n".join(
        f"  - `{signal}_A1..A7` ({unit}): {description}"
        for signal, (unit, description) in JOINT_SIGNALS.items()
    )
    chosen_text = (
        "every Pareto-front controller"
        if selection == "front"
        else "the knee (the front member `analytic export` takes: the least worse objective, both "
        "on a log scale between the front's ideal and nadir)"
    )
    runs = "\n".join(
        f"- `{run.name}`: run_id `{run.run_id}`, {interface_text(run.model)}" for run in chosen
    )
    fractions = ",".join(f"{value:g}" for value in split)
    if counts["linked"] + counts["copied"] == 0:
        logs = "the rerun's own, none a tuning run's"
    elif counts["copied"] == 0:
        logs = "hard links to the runs' own logs (the same inode, no second copy)"
    elif counts["linked"] == 0:
        logs = "copies of the runs' logs (the file system refused hard links)"
    else:
        logs = (
            f"{counts['linked']} hard links to the runs' own logs and {counts['copied']} copies "
            "(where the file system refused a link)"
        )
    rerun = (
        f" The {counts['rerun']} rerun episodes' logs were written for this dataset."
        if counts["rerun"]
        else ""
    )
    variants = counts.get("rerun_plants", 0)
    rerun_line = (
        f", and each of them run once more on the {counts['rerun_trajectories']} trajectories of "
        "the rerun (`source` rerun)"
        + (
            f", on its run's plant and on {variants} variants of it drawn from the plant's "
            "uncertainty ranges (models/uncertainty.toml; the `model` column says which)"
            if variants
            else ""
        )
        if counts["rerun"]
        else ""
    )
    caution = " Do not edit a log in place: a hard-linked one changes in its run too." * bool(
        counts["linked"]
    )
    left_out = counts.get("infeasible_left_out", 0)
    limits = (
        f" {left_out} episodes of controllers that break their run's safety limits were left "
        "out (`analytic dataset --infeasible` keeps them)."
        if left_out
        else ""
    )
    rough_out = counts.get("rough_left_out", 0)
    if rough_out:
        limits += (
            f" {rough_out} episodes that chatter or diverged were left out (`--include-rough` "
            "keeps them)."
        )
    elif counts.get("rough", 0):
        limits += (
            f" {counts['rough']} episodes chatter or diverged, kept by `--include-rough`: their "
            "`calm` is false; score a model on the calm ones."
        )
    command = f"analytic dataset ... --select {selection} --split {fractions}"
    command += f" --split-seed {split_seed}" + (" --rerun FILE" if counts["rerun"] else "")
    command += f" --plants {variants}" * bool(variants)
    command += " --include-rough" * bool(counts.get("rough", 0))
    opening = _paragraph(
        "Torque, position and velocity episodes of a simulated KUKA LBR iiwa 14 (MuJoCo, "
        "elastic joints unless the `model` column says otherwise) under PD controllers tuned by "
        f"NSGA-II for tracking accuracy and torque smoothness: {chosen_text} of each run below, "
        f"on each trajectory it was tuned on{rerun_line}."
    )
    summary = _paragraph(
        f"{counted(counts['episodes'], 'episode')}, {counts['ticks']:,} ticks at 500 Hz (control "
        f"period {CONTROL_PERIOD} s), {counted(counts['controllers'], 'controller')} from "
        f"{counted(counts['runs'], 'run')}, on "
        f"{counted(counts['trajectories'], 'trajectory')}. Dataset version "
        f"{DATASET_VERSION}.{limits}"
    )
    on_variants = counts.get("on_variants", 0)
    variant_text = (
        "\n\n"
        + _paragraph(
            f"One plant per part: the {on_variants} episodes on a plant other than their run's "
            "own (a robust run's tuning variants, the rerun's `--plants`) are in "
            "`train_variants`, `validation_variants` and `test_variants`, by the same "
            "trajectories. `train`, `validation` and `test` hold the runs' own plants: the same "
            "motion asks for other torques on another plant, a spread no model without the "
            "plant among its inputs can learn. Train on the variants too to learn across plants; "
            "`test_variants` measures what a model of one plant misses on the others."
        )
        if on_variants
        else ""
    )
    return f"""# gainfarm dynamics dataset

{opening}

{summary}

{runs}

## Split

By trajectory, never by tick: every tick of every episode of one `trajectory_id` is in the same
part, so a model is tested on motions it never saw. Fractions {fractions} (train, validation,
test) of the trajectories, ordered by the SHA-256 of `<split seed>:<trajectory_id>` (split seed
{split_seed}), each part with a positive fraction given at least one: {counts["train"]} train,
{counts["validation"]} validation, {counts["test"]} test trajectories.{variant_text}

## Files

- `ticks.parquet`: one row per 2 ms control tick. `episode_id`, `trajectory` (its kind),
  `trajectory_id`, `split`, `t` (s since the episode started), and per joint:
{joint_columns}

  and `ee_x..z`, `ee_des_x..z` (flange position and its desired value, m, base frame).
  Row `k` of an episode is tick `k` of its MCAP log: the state sensed at tick `k` and the command
  `u` then applied until tick `k + 1`. `qdd` is computed within each episode, `(qd[k+1] - qd[k]) /
  {CONTROL_PERIOD}`: the acceleration produced while row `k`'s `u` was applied, so it pairs with
  `u` exactly; it is NaN on each episode's last tick (never a difference across two episodes).
  `qdd_sg` is the acceleration at tick `k` from a Savitzky-Golay fit of `q` (order {SG_ORDER},
  {SG_WINDOW} ticks centred on `k`, within the episode): the difference's noise gives even the
  plant's own model a test nMSE near 0.09 on the realistic plant, this fit near 0.001. Learn and
  score on `qdd_sg`. Motor side (`theta`, `theta_d`) and torque sensors (`tau`) are as the sensors
  report them, noise included on the realistic plant; `u` is the controller's command as the robot
  took it (after the plant's delay and saturation), and `u_motor` the torque the motors exerted:
  behind KUKA's FRI torque interface, `u` plus the robot's own gravity model at the angles it
  measured (the fed-back side's `theta` or `q`), saturated; on a plain torque interface, `u`. A
  model of the arm's dynamics predicts `u_motor`. Each run above says its interface; the `model`
  column of `episodes.parquet` says which plant: interface, friction, delay, sensors, feedback
  side.
- `episodes.parquet`: one row per episode. `episode_id` (`<first 8 hex digits of the
  run_id>-<job id>`, with `-rerun-` for reruns), `run` (the run directory's name, or `rerun`),
  `run_id` (the controller's run, from its run.json), `source` (`tuning` or `rerun`),
  `trajectory_id`, `kp_A1..A7` (N·m/rad), `kd_A1..A7` (N·m·s/rad), `f_acc` (mean end-effector
  error, m), `f_t` (mean squared torque change per tick, (N·m)²), `diverged`, `ticks`,
  `trajectory`, `duration` (s), `trajectory_spec` and `model` (JSON), `gravity_compensation`,
  `feedforward` (the learned model's SHA-256, or empty),
  `candidate_f_acc`, `candidate_f_t` (the controller's objectives over its run's trajectory set),
  the safety measures `torque_step`, `saturated_fraction`, `speed`, `chatter`, `lag` (rad),
  `within_limits`, `calm` (ran to its end, chatter within {CALM_CHATTER:g}), `split`.
- `trajectories.parquet`: one row per distinct trajectory. `trajectory_id` (the first
  {TRAJECTORY_ID_DIGITS} hex digits of the SHA-256 of `spec`), `kind`, `seed`, `center_x..z` (m),
  `size` (m), `duration` (s), `twist` (rad), `turns`, `waypoints`, `harmonics`, `spec` (the
  TrajectorySpec as canonical JSON: sorted keys, no spaces), `split`, `episodes`.
- `episodes/<episode_id>.mcap`: the original logs (ROS 2 CDR: `/joint_states`,
  `/joint_commands`, `/motor_states`, `/joint_reference`, `/ee/actual`, `/ee/desired`, and in
  recent logs, for ROS 2 tools such as Foxglove, `/tf` and `/robot_description`: the arm's links
  at 50 Hz and its URDF; the channel contract is in gainfarm's schemas/README.md), each with its
  full spec in the `gainfarm.episode` metadata record. They are {logs}.{rerun}{caution}

Every Parquet column carries its unit (`unit`: rad, rad/s, rad/s^2, N*m, m, s, or empty for ids
and counts) and a `description` in its field metadata; each table's schema metadata holds the
`control_period` (s), the `dataset_version`, the `split` and the `split_seed`.

Made with:

    {command}
"""
