"""Cost of one episode on the realistic and the ideal plant, against a C physics loop, and of
scoring it from its log.

    python bench/episode_bench.py [--repeats 15] [--duration 5]

All timings are medians over interleaved repeats in one run, so that the ratios compare like
with like on a shared, noisy machine. The C loop is MuJoCo's own `rollout` (mj_step in C, no
Python per step) on the realistic plant's model, stepped as many times from the same state with
the motors holding the arm against gravity (so that, like a tracking episode, it neither falls
into the joint limits nor does anything else): the cost of the physics alone.
"""

import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import click
import mujoco
import numpy as np
from common import print_table
from mujoco import rollout

from gainfarm.edges.files import write_atomically
from gainfarm.models.urdf import description
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.mcap_episode import episode_bytes, read_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import IDEAL_PLANT, REALISTIC_PLANT
from gainfarm.worker.episode import gravity_torques, run_episode
from gainfarm.worker.plant import Plant
from gainfarm.worker.reference import reference_for


def write_log(log: EpisodeLog, path: Path) -> int:
    """Write `log` to `path` as `worker episode --out` does; return its size."""
    content = episode_bytes(log, description())
    write_atomically(path, content)
    return len(content)


def c_loop(spec: EpisodeSpec) -> Callable[[], None]:
    """The episode's model stepped in C as many times from its first state, the motors holding
    the arm against gravity: the cost of the physics alone."""
    reference = reference_for(spec.trajectory)
    plant = Plant(spec.model)
    plant.reset(reference.q[0])
    signature = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.empty(mujoco.mj_stateSize(plant.model, signature))
    mujoco.mj_getState(plant.model, plant.data, initial, signature)
    steps = spec.trajectory.ticks * plant.substeps
    hold = gravity_torques(reference.q[:1], spec.model.inertials)
    control = np.tile(hold, (steps, 1))

    def run() -> None:
        rollout.rollout(plant.model, plant.data, initial, control)

    return run


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--repeats", type=click.IntRange(min=1), default=15, show_default=True)
@click.option(
    "--duration",
    type=click.FloatRange(min=0, min_open=True),
    default=5.0,
    show_default=True,
    help="s per episode",
)
def main(repeats: int, duration: float) -> None:
    trajectory = TrajectorySpec(duration=duration)
    realistic = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=trajectory, model=REALISTIC_PLANT)
    ideal = realistic.model_copy(update={"model": IDEAL_PLANT})
    reference_for(trajectory)  # the IK runs once per trajectory; it is not per-episode cost
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / "episode.mcap"
        size = write_log(run_episode(realistic), path)
        cases: dict[str, Callable[[], object]] = {
            "C mj_step loop (rollout)": c_loop(realistic),
            "ideal episode": lambda: run_episode(ideal),
            "realistic episode": lambda: run_episode(realistic),
            "realistic episode + MCAP log": lambda: write_log(run_episode(realistic), path),
            "score from MCAP": lambda: score(read_episode(path)),
        }
        times: dict[str, list[float]] = {name: [] for name in cases}
        for _ in range(repeats):
            for name, case in cases.items():
                start = time.perf_counter()
                case()
                times[name].append(time.perf_counter() - start)

    median = {name: statistics.median(values) for name, values in times.items()}
    bare, ideal_time = median["C mj_step loop (rollout)"], median["ideal episode"]
    logged = median["realistic episode + MCAP log"]
    print(
        f"{duration:g} s episode, {trajectory.ticks} ticks, {realistic.model.joints} joints, "
        f"{realistic.model.substeps} physics steps per tick, median of {repeats}\n"
    )

    def row(name: str, seconds: float) -> tuple[str, str, str, str]:
        if name == "score from MCAP":
            return name, f"{seconds * 1000:.1f}", f"{seconds / logged:.2f} of logged episode", ""
        return name, f"{seconds * 1000:.1f}", f"{seconds / bare:.2f}", f"{seconds / ideal_time:.2f}"

    print_table(
        ("case", "ms", "x C loop", "x ideal"), "lrrr", (row(*item) for item in median.items())
    )
    print(f"\nreal-time factor (realistic episode + log): {duration / logged:.0f}x")
    print(f"bytes per episode: {size:,}")


if __name__ == "__main__":
    main()
