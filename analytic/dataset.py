"""The dataset for learning the cobot's dynamics: the tuned controllers' episodes, gathered.

From one or more tuning runs, take the selected controllers (the whole Pareto front, or its knee)
and their episodes on each trajectory, and write a dataset directory:

    episodes/<run>-<job>.mcap   the MCAP logs, as the workers wrote them
    ticks.parquet               one row per 2 ms tick of every episode
    episodes.parquet            one row per episode: gains, objectives, trajectory, model
    README.md                   the dataset card

The directory appears whole or not at all: it is built beside its destination and renamed.
"""

import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from analytic.evolution import normalise
from analytic.records import FrontMember, RunRecord, read_run
from analytic.run import upgrade
from schemas.episode_log import EpisodeLog
from schemas.files import write_atomically
from schemas.mcap_episode import read_episode
from schemas.objectives import score
from schemas.robot import JOINT_NAMES

Selection = Literal["front", "knee"]

# rad, rad/s, N·m, N·m, rad, rad/s, rad, rad/s
JOINT_SIGNALS = ("q", "qd", "tau", "u", "theta", "theta_d", "q_des", "qd_des")
CARTESIAN_SIGNALS = ("ee", "ee_des")  # m, in the base frame
AXES = ("x", "y", "z")


class NoEpisodes(ValueError):
    pass


class UnreadableRun(ValueError):
    pass


@dataclass(frozen=True)
class Source:
    """One episode going into the dataset."""

    episode_id: str
    run: str
    path: Path
    member: FrontMember


def select(run: RunRecord, selection: Selection) -> list[FrontMember]:
    """The front, or its knee: the member nearest the ideal point in the hypervolume's space."""
    front = run.front
    if selection == "front" or not front:
        return front
    normalised = normalise([member.objectives for member in front], run.config.reference_point)
    return [front[int(np.argmin(np.hypot(normalised[:, 0], normalised[:, 1])))]]


def sources(run_dirs: Sequence[Path], selection: Selection) -> list[Source]:
    """Every kept log of the selected members, read from each run's front.json."""
    found = []
    for run_dir in run_dirs:
        try:
            upgrade(run_dir)
            run = read_run(run_dir)
        except (OSError, ValueError) as error:
            raise UnreadableRun(f"{str(run_dir)!r}: unreadable run ({error})") from None
        name = Path(run_dir).resolve().name
        for member in select(run, selection):
            for log in member.logs:
                path = Path(run_dir) / log
                if path.is_file():
                    found.append(Source(f"{name}-{path.stem}", name, path, member))
    if not found:
        raise NoEpisodes(
            "none of the selected controllers has an episode log in its run's episodes/"
        )
    return found


def tick_columns(episode_id: str, log: EpisodeLog) -> dict[str, np.ndarray]:
    """The ticks of one episode as flat, named columns (q_A1 ... ee_des_z)."""
    columns: dict[str, np.ndarray] = {
        "episode_id": np.full(log.ticks, episode_id, dtype=object),
        "trajectory": np.full(log.ticks, log.metadata.spec.trajectory.kind.value, dtype=object),
        "t": log.t,
    }
    for signal in JOINT_SIGNALS:
        values = getattr(log, signal)
        for index, joint in enumerate(JOINT_NAMES):
            columns[f"{signal}_{joint}"] = values[:, index]
    for signal in CARTESIAN_SIGNALS:
        values = getattr(log, signal)
        for index, axis in enumerate(AXES):
            columns[f"{signal}_{axis}"] = values[:, index]
    return columns


def episode_row(source: Source, log: EpisodeLog) -> dict[str, object]:
    spec = log.metadata.spec
    scores = score(log)
    row: dict[str, object] = {"episode_id": source.episode_id, "run": source.run}
    row |= {f"kp_{joint}": gain for joint, gain in zip(JOINT_NAMES, spec.gains.kp, strict=True)}
    row |= {f"kd_{joint}": gain for joint, gain in zip(JOINT_NAMES, spec.gains.kd, strict=True)}
    row |= {
        "f_acc": scores.f_acc,
        "f_t": scores.f_t,
        "diverged": scores.diverged,
        "ticks": log.ticks,
        "trajectory": spec.trajectory.kind.value,
        "duration": spec.trajectory.duration,
        "trajectory_spec": spec.trajectory.model_dump_json(),
        "model": spec.model.model_dump_json(),
        "gravity_compensation": spec.gravity_compensation,
        "candidate_f_acc": source.member.f_acc,
        "candidate_f_t": source.member.f_t,
    }
    return row


def build(run_dirs: Sequence[Path], out: Path, selection: Selection = "front") -> dict[str, int]:
    """Write the dataset to `out` (which must not exist); return its counts."""
    out = Path(out)
    if out.exists():
        raise FileExistsError(f"{out} already exists")
    chosen = sources(run_dirs, selection)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.", suffix=".part"))
    try:
        (staging / "episodes").mkdir()
        ticks, rows = [], []
        for source in chosen:
            log = read_episode(source.path)
            shutil.copyfile(source.path, staging / "episodes" / f"{source.episode_id}.mcap")
            ticks.append(pa.table(tick_columns(source.episode_id, log)))
            rows.append(episode_row(source, log))
        pq.write_table(pa.concat_tables(ticks), staging / "ticks.parquet", compression="zstd")
        pq.write_table(pa.Table.from_pylist(rows), staging / "episodes.parquet")
        counts = {
            "episodes": len(rows),
            "ticks": sum(table.num_rows for table in ticks),
            "controllers": len({source.member.gains for source in chosen}),
            "runs": len({source.run for source in chosen}),
        }
        write_atomically(staging / "README.md", card(counts, run_dirs, selection).encode())
        staging.rename(out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return counts


def card(counts: dict[str, int], run_dirs: Sequence[Path], selection: Selection) -> str:
    joint_columns = ", ".join(f"`{signal}_A1..A7`" for signal in JOINT_SIGNALS)
    chosen = "every Pareto-front controller" if selection == "front" else "each run's knee"
    runs = "\n".join(f"- `{Path(run_dir).resolve().name}`" for run_dir in run_dirs)
    return f"""# gainfarm dynamics dataset

Torque, position and velocity episodes of a simulated KUKA LBR iiwa 14 (MuJoCo, elastic joints
unless the `model` column says otherwise) under PD controllers tuned by NSGA-II for tracking
accuracy and torque smoothness: {chosen} of the runs below, on each trajectory it was tuned on.

{counts["episodes"]} episodes, {counts["ticks"]:,} ticks at 500 Hz, {counts["controllers"]}
controllers from {counts["runs"]} runs:

{runs}

## Files

- `ticks.parquet`: one row per 2 ms control tick. `episode_id`, `trajectory`, `t` (s since the
  episode started), {joint_columns} (what the sensors report: link-side position and
  velocity, rad and rad/s, the joint torque sensors' reading, N·m; the torque command as applied
  to the motors, delayed and saturated, N·m; motor-side angle and velocity; desired position
  and velocity), `ee_x..z` and `ee_des_x..z` (flange position and its desired value, m, base
  frame). The `model` column says which plant: its friction, delay, sensors and feedback side.
- `episodes.parquet`: one row per episode. `episode_id`, `run`, `kp_A1..A7`, `kd_A1..A7`,
  `f_acc` (mean end-effector error, m), `f_t` (mean squared torque change per tick, (N·m)²),
  `diverged`, `ticks`, `trajectory`, `duration`, `trajectory_spec` and `model` (JSON),
  `gravity_compensation`, and the controller's objectives over its run's trajectory set.
- `episodes/<episode_id>.mcap`: the original logs (ROS 2 CDR: `/joint_states`,
  `/joint_commands`, `/motor_states`, `/joint_reference`, `/ee/actual`, `/ee/desired`; the
  channel contract is in gainfarm's
  schemas/README.md), each with its full spec in the `gainfarm.episode` metadata record.

Row `k` of an episode in `ticks.parquet` is tick `k` of its MCAP log: the state sensed at tick `k`
and the command then applied until tick `k + 1`.

Made with `analytic dataset ... --select {selection}`.
"""
