"""Cost of one episode against a bare physics loop, and of scoring it from its log.

    python bench/episode_bench.py [--repeats 15] [--duration 5]

All timings are medians over interleaved repeats in one run, so that the ratios compare like
with like on a shared, noisy machine. The bare loop steps the same model the same number of
times from the same state, with the motors holding the arm against gravity (so that, like a
tracking episode, it neither falls into the joint limits nor does anything else).
"""

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import mujoco

from schemas import EpisodeSpec, PDGains, TrajectorySpec
from schemas.mcap_episode import read_episode, write_episode
from schemas.objectives import score
from worker.cli import DEFAULT_KD, DEFAULT_KP
from worker.episode import run_episode
from worker.plant import Plant
from worker.reference import reference_for


def bare_loop(spec: EpisodeSpec) -> Callable[[], None]:
    reference = reference_for(spec.trajectory)
    plant = Plant(spec.model)

    def run() -> None:
        plant.reset(reference.q[0])
        plant.data.ctrl[:] = reference.gravity[0]
        for _ in range(spec.trajectory.ticks):
            mujoco.mj_step(plant.model, plant.data, plant.substeps)

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--duration", type=float, default=5.0)
    args = parser.parse_args()

    gains = PDGains(
        kp=tuple(map(float, DEFAULT_KP.split(","))), kd=tuple(map(float, DEFAULT_KD.split(",")))
    )
    spec = EpisodeSpec(gains=gains, trajectory=TrajectorySpec(duration=args.duration))
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
        for _ in range(args.repeats):
            for name, case in cases.items():
                start = time.perf_counter()
                case()
                times[name].append(time.perf_counter() - start)

    median = {name: statistics.median(values) for name, values in times.items()}
    bare, episode = median["bare mj_step loop"], median["episode + MCAP log"]
    print(
        f"{args.duration:g} s episode, {spec.trajectory.ticks} ticks, {spec.model.joints} joints, "
        f"{spec.model.substeps} physics steps per tick, median of {args.repeats}\n"
    )
    print("| case | ms | ratio |")
    print("|---|---:|---:|")
    for name, seconds in median.items():
        base, label = (
            (episode, "of episode + log") if name == "score from MCAP" else (bare, "x bare")
        )
        print(f"| {name} | {seconds * 1000:.1f} | {seconds / base:.2f} {label} |")
    print(f"\nreal-time factor (episode + log): {args.duration / episode:.0f}x")
    print(f"bytes per episode: {size:,}")


if __name__ == "__main__":
    main()
