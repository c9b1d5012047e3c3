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

A dataset is of one arm, the runs' robot (runs of two arms are refused): its per-joint columns
are named by that arm's joints, and every table's metadata names the robot and its joints
(dataset_columns.arm_metadata).

The directory appears whole or not at all: it is built beside its destination and renamed.

This module builds it; its parts are modules of their own: the runs and controllers it takes
(analytic.data.dataset_runs), the split (dataset_split), the columns and their units
(dataset_columns) and the card (dataset_card).
"""

import contextlib
import hashlib
import json
import math
import os
import shutil
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import TypeAdapter, ValidationError
from scipy.signal import savgol_filter

from gainfarm.analytic.compose import new_study_name
from gainfarm.analytic.data.dataset_card import card, interface_text
from gainfarm.analytic.data.dataset_columns import (
    AXES,
    CALM_CHATTER,
    CARTESIAN_SIGNALS,
    COLUMNS,
    DATASET_VERSION,
    JOINT_SIGNALS,
    LOGGED_JOINT_SIGNALS,
    ROBOT_BEFORE,
    SG_ORDER,
    SG_WINDOW,
    TRAJECTORY_ID_DIGITS,
    arm_metadata,
    column_unit,
    with_units,
)
from gainfarm.analytic.data.dataset_runs import (
    ChosenRun,
    DuplicateEpisodes,
    Selection,
    UnreadableRun,
    choose,
    run_id_of,
    select,
)
from gainfarm.analytic.data.dataset_split import (
    DEFAULT_SPLIT,
    BadSplit,
    Split,
    assign_splits,
    check_split,
    split_counts,
)
from gainfarm.analytic.data.loader import SPLITS, VARIANTS
from gainfarm.analytic.evaluators.batch import batch_jobs, run_batch
from gainfarm.analytic.evaluators.evaluator import EpisodeStatus, Evaluator
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.tuning.plants import HELD_OUT, variants
from gainfarm.analytic.tuning.records import (
    FrontMember,
)
from gainfarm.edges.files import staging_directory, write_atomically
from gainfarm.models import robot_of
from gainfarm.plugins import OBJECTIVES, load_plugins
from gainfarm.schemas.documents import quoted
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.limits import MEASURES
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, read_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD, TrajectorySpec
from gainfarm.schemas.wire import describe
from gainfarm.worker.episode import motor_torque
from gainfarm.worker.ik import UnreachablePath
from gainfarm.worker.reference import InfeasibleReference, reference_for

# The dataset's names, where they were before its card, columns, split and choice of runs had
# modules of their own, and are imported from still.
__all__ = [
    "AXES",
    "CALM_CHATTER",
    "CARTESIAN_SIGNALS",
    "COLUMNS",
    "DATASET_VERSION",
    "DEFAULT_SPLIT",
    "EXCITATION_DURATION",
    "JOINT_SIGNALS",
    "LOGGED_JOINT_SIGNALS",
    "RERUN",
    "RERUN_DIR",
    "RUN_ID_DIGITS",
    "SG_ORDER",
    "SG_WINDOW",
    "SPLITS",
    "TRAJECTORY_ID_DIGITS",
    "TUNING",
    "BadRerun",
    "BadSplit",
    "ChosenRun",
    "DuplicateEpisodes",
    "Episode",
    "EpisodeSource",
    "MixedArms",
    "NoEpisodes",
    "RerunFailed",
    "RerunFarm",
    "Selection",
    "Split",
    "UnreadableRun",
    "assign_splits",
    "build",
    "calm_only",
    "canonical_json",
    "card",
    "check_rerun",
    "check_split",
    "choose",
    "column_unit",
    "episode_row",
    "excitations",
    "interface_text",
    "is_calm",
    "link_or_copy",
    "local_rerun_farm",
    "plant_of",
    "plant_variants",
    "read_rerun",
    "read_source",
    "refuse_duplicates",
    "rerun",
    "rerun_jobs",
    "run_id_of",
    "select",
    "smoothed_acceleration",
    "sources",
    "split_counts",
    "tick_columns",
    "trajectory_id",
    "trajectory_row",
    "with_units",
    "within_limits",
]

RUN_ID_DIGITS = 8  # of the run's 32: unique enough, and a collision is refused, not merged
TUNING, RERUN = "tuning", "rerun"  # the `source` column: where an episode comes from
RERUN_DIR = "rerun"  # the rerun's batch directory, inside the staging directory
EXCITATION_DURATION = 10.0  # s, each of `--excitations`: 5,000 ticks


class NoEpisodes(ValueError):
    pass


class BadRerun(ValueError):
    """A rerun trajectory list that is not one, or a trajectory the robot cannot follow."""


class RerunFailed(ValueError):
    """A rerun episode did not run: the dataset would be missing it."""


class MixedArms(ValueError):
    """Runs of two arms: a dataset's columns are one arm's joints."""


# Given the directory a rerun's batch writes into, a context giving the evaluator to run it on.
RerunFarm = Callable[[Path], AbstractContextManager[Evaluator]]


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


def check_rerun(
    trajectories: Sequence[TrajectorySpec], followable: bool = True, robot: str = ROBOT_BEFORE
) -> None:
    """A non-empty list without repeats (a repeat would be the same episode twice), and, with
    `followable`, only trajectories `robot` can follow (every episode of another would fail)."""
    if not trajectories:
        raise BadRerun("the list of trajectories is empty")
    first: dict[str, int] = {}
    for number, trajectory in enumerate(trajectories, start=1):
        earlier = first.setdefault(canonical_json(trajectory), number)
        if earlier != number:
            raise BadRerun(f"trajectory {number} repeats trajectory {earlier}")
    if not followable:
        return
    for number, trajectory in enumerate(trajectories, start=1):
        try:
            reference_for(trajectory, robot)
        except (InfeasibleReference, UnreachablePath) as error:
            what = f"{trajectory.kind}, {trajectory.duration:g} s"
            raise BadRerun(f"trajectory {number} ({what}): {error}") from None


def tick_columns(episode_id: str, log: EpisodeLog) -> dict[str, np.ndarray]:
    """The ticks of one episode as flat, named columns (t, q_A1 ... ee_des_z: its arm's joints),
    the split aside.

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
        for index, joint in enumerate(joints_of(log)):
            columns[f"{signal}_{joint}"] = signals[signal][:, index]
    for signal in CARTESIAN_SIGNALS:
        values = getattr(log, signal)
        for index, axis in enumerate(AXES):
            columns[f"{signal}_{axis}"] = values[:, index]
    return columns


def joints_of(log: EpisodeLog) -> tuple[str, ...]:
    """The joints of the arm an episode ran on, as its log names them: its columns' names."""
    return tuple(log.metadata.joint_names)


def arm_of(chosen: Sequence[ChosenRun]) -> str:
    """The one robot of the chosen runs; MixedArms, one line, if they are of two."""
    robots = list(dict.fromkeys(run.plant.robot for run in chosen))
    if len(robots) > 1:
        raise MixedArms(
            f"the runs are of {len(robots)} arms ({', '.join(robots)}): a dataset is of one arm "
            "(its columns are its joints); build one per arm"
        )
    return robots[0] if robots else ROBOT_BEFORE


def smoothed_acceleration(q: np.ndarray, period: float) -> np.ndarray:
    """q̈ of one episode's (n, N) angles: the Savitzky-Golay fit's second derivative (SG_WINDOW,
    SG_ORDER), the window's edges fitted by one polynomial ("interp"); NaN if the episode is
    shorter than the window."""
    if len(q) < SG_WINDOW:
        return np.full(np.shape(q), np.nan)
    return savgol_filter(q, SG_WINDOW, SG_ORDER, deriv=2, delta=period, axis=0, mode="interp")


def plant_of(episode: Episode) -> PlantSpec:
    return PlantSpec.model_validate_json(str(episode.row["model"]))


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
    joints = joints_of(log)
    row |= {f"kp_{joint}": gain for joint, gain in zip(joints, spec.gains.kp, strict=True)}
    row |= {f"kd_{joint}": gain for joint, gain in zip(joints, spec.gains.kd, strict=True)}
    row |= {
        "f_acc": scores.f_acc,
        "f_t": scores.f_t,
        "diverged": scores.diverged,
        "ticks": log.ticks,
        "trajectory": spec.trajectory.kind,
        "duration": spec.trajectory.duration,
        "trajectory_spec": spec.trajectory.model_dump_json(),
        "model": spec.plant.model_dump_json(),
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


def plant_variants(nominal: PlantSpec, count: int, seed: int) -> tuple[PlantSpec, ...]:
    """`count` plants around `nominal`, drawn from the shipped uncertainty ranges
    (models/uncertainty.toml) on the held-out stream: never the plants a robust run tuned on."""
    if count == 0:
        return ()
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
        models = (run.plant, *plant_variants(run.plant, plants, seed))
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
        result = evaluations.get(job_id)
        if (
            result is None
            or result.log is None
            or result.status
            not in (
                EpisodeStatus.ok,
                EpisodeStatus.diverged,
            )
        ):
            status = result.status.value if result else "lost"
            reason = f": {result.reason}" if result and result.reason else ""
            raise RerunFailed(f"rerun episode {job_id} {status}{reason}; nothing was written")
        run, member, episode_id = owners[job_id]
        path = staging / "episodes" / f"{episode_id}.mcap"
        os.replace(result.log, path)
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
    robot = arm_of(chosen)
    joints = robot_of(robot).joint_names
    found = sources(chosen)
    if rerun_trajectories:
        check_rerun(rerun_trajectories, robot=robot)
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
        own = {run.run_id: run.plant for run in chosen}
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
        } | arm_metadata(robot, joints)
        ticks = pa.concat_tables(
            episode.ticks.add_column(
                episode.ticks.schema.get_field_index("t"),
                "split",
                pa.array([parts[episode.source.episode_id]] * episode.ticks.num_rows),
            )
            for episode in episodes
        )
        pq.write_table(
            with_units(ticks, metadata | {"table": "ticks"}, joints),
            staging / "ticks.parquet",
            compression="zstd",
        )
        rows = [episode.row | {"split": parts[episode.source.episode_id]} for episode in episodes]
        pq.write_table(
            with_units(pa.Table.from_pylist(rows), metadata | {"table": "episodes"}, joints),
            staging / "episodes.parquet",
        )
        per_trajectory = Counter(str(row["trajectory_id"]) for row in rows)
        trajectory_rows = [
            trajectory_row(trajectory) | {"split": splits[tid], "episodes": per_trajectory[tid]}
            for tid, trajectory in sorted(trajectories.items())
        ]
        pq.write_table(
            with_units(
                pa.Table.from_pylist(trajectory_rows), metadata | {"table": "trajectories"}, joints
            ),
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
