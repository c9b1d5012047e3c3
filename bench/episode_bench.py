"""Cost of one episode against a bare physics loop, and of scoring it from its log.

    python bench/episode_bench.py [--repeats 15] [--duration 5]

All timings are medians over interleaved repeats in one run, so that the ratios compare like
with like on a shared, noisy machine. The bare loop steps the same model the same number of
times from the same state, with the motors holding the arm against gravity (so that, like a
tracking episode, it neither falls into the joint limits nor does anything else).
"""

import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import click
import mujoco
from common import print_table

from schemas import EpisodeSpec, TrajectorySpec
from schemas.gains import DEFAULT_GAINS
from schemas.mcap_episode import read_episode, write_episode
from schemas.objectives import score
from worker.episode import run_episode
from worker.plant import Plant
from worker.reference import reference_for


def bare_loop(spec: EpisodeSpec) -> Callable[[], None]:
    """The episode's model stepped as many times from its first state, the motors holding the
    arm against gravity: the cost of the physics alone."""
    reference = reference_for(spec.trajectory)
    plant = Plant(spec.model)

    def run() -> None:
        plant.reset(reference.q[0])
        plant.data.ctrl[:] = reference.gravity[0]
        for _ in range(spec.trajectory.ticks):
            mujoco.mj_step(plant.model, plant.data, plant.substeps)

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
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=TrajectorySpec(duration=duration))
    reference_for(spec.trajectory)  # the IK runs once per trajectory; it is not per-episode cost
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / "episode.mcap"
        size = write_episode(run_episode(spec), path)
        cases: dict[str, Callable[[], object]] = {
            "bare mj_step loop": bare_loop(spec),
            "episode (simulation + control)": lambda: run_episode(spec),
            "episode + MCAP log": lambda: write_episode(run_episode(spec), path),
            "score from MCAP": lambda: score(read_episode(path)),
        }
        times: dict[str, list[float]] = {name: [] for name in cases}
        for _ in range(repeats):
            for name, case in cases.items():
                start = time.perf_counter()
                case()
                times[name].append(time.perf_counter() - start)

    median = {name: statistics.median(values) for name, values in times.items()}
    bare, episode = median["bare mj_step loop"], median["episode + MCAP log"]
    print(
        f"{duration:g} s episode, {spec.trajectory.ticks} ticks, {spec.model.joints} joints, "
        f"{spec.model.substeps} physics steps per tick, median of {repeats}\n"
    )

    def row(name: str, seconds: float) -> tuple[str, str, str]:
        base, label = (
            (episode, "of episode + log") if name == "score from MCAP" else (bare, "x bare")
        )
        return name, f"{seconds * 1000:.1f}", f"{seconds / base:.2f} {label}"

    print_table(("case", "ms", "ratio"), "lrr", (row(*item) for item in median.items()))
    print(f"\nreal-time factor (episode + log): {duration / episode:.0f}x")
    print(f"bytes per episode: {size:,}")


if __name__ == "__main__":
    main()
