"""The farm's efficiency: episodes per second through a local farm, over a process pool doing the
same work.

    python bench/farm_efficiency.py [--quick] [--episodes 40] [--duration 5] [--rounds 5]

The same N episodes (5 s spirals, gains from 0.8x to 1.2x the defaults, so alike but not equal)
run through a local farm -- the broker in this process, 2 worker processes, a FarmClient that
decodes, checks, scores and writes every log into a temporary run directory -- and through
multiprocessing's Pool(2), whose tasks run the episode and encode its log as a worker does while
this process decodes, checks, scores and writes it the same way. The only difference is the
transport and the broker. Both first run a warm-up batch of 2 episodes per process (the first
episode in a process compiles the model and computes the reference); then farm and pool rounds
alternate, and the figure is the median episodes per second of the farm's rounds over the median
of the pool's.

Everything listens on loopback, on a port the kernel picked as free; nothing touches a farm on 7447.
"""

import statistics
import tempfile
import time
from dataclasses import dataclass
from multiprocessing.pool import Pool
from pathlib import Path

import click
from common import SPAWN, episode_specs

from gainfarm.analytic.evaluators.evaluator import EpisodeStatus, accept_log
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.schemas import EpisodeSpec
from gainfarm.worker.job import simulate

WORKERS = 2  # farm workers and pool processes


def pool_task(task: tuple[str, EpisodeSpec]) -> tuple[str, bytes]:
    """What a farm worker does with a job, short of putting the result."""
    job_id, spec = task
    return job_id, simulate(spec).content


def keep(content: bytes, spec: EpisodeSpec, path: Path) -> None:
    """What FarmClient does with a result's log: decode, check, write atomically, score."""
    if accept_log(content, spec, path, path.name).diverged:
        raise RuntimeError(f"{path.name}: diverged")


def farm_round(farm: FarmClient, specs: list[EpisodeSpec], tag: str) -> float:
    """Episodes per second through the farm, from submission to the last scored result."""
    jobs = {f"{tag}-{index}": spec for index, spec in enumerate(specs)}
    start = time.perf_counter()
    farm.submit(jobs)
    evaluations = list(farm.results(timeout=600))
    elapsed = time.perf_counter() - start
    bad = [e.job_id for e in evaluations if e.status != EpisodeStatus.ok]
    if len(evaluations) != len(jobs) or bad:
        raise RuntimeError(f"farm round {tag}: {len(evaluations)} results, not ok: {bad[:5]}")
    return len(specs) / elapsed


def pool_round(pool: Pool, specs: list[EpisodeSpec], episodes: Path, tag: str) -> float:
    """Episodes per second through the pool, this process doing FarmClient's share."""
    by_id = {f"{tag}-{index}": spec for index, spec in enumerate(specs)}
    start = time.perf_counter()
    for job_id, content in pool.imap_unordered(pool_task, by_id.items(), chunksize=1):
        keep(content, by_id[job_id], episodes / f"{job_id}.mcap")
    return len(specs) / (time.perf_counter() - start)


@dataclass
class Efficiency:
    farm: list[float]  # episodes/s, one per round
    pool: list[float]
    duplicates: int  # results FarmClient received for jobs it had done already

    @property
    def ratio(self) -> float:
        return statistics.median(self.farm) / statistics.median(self.pool)


def efficiency(count: int, duration: float, rounds: int) -> Efficiency:
    specs = episode_specs(count, duration)
    warm_up = episode_specs(2 * WORKERS, duration)
    outcome = Efficiency([], [], 0)
    with (
        tempfile.TemporaryDirectory() as scratch,
        local_farm(WORKERS) as endpoint,
        FarmClient([endpoint], "bench-efficiency", Path(scratch) / "farm") as farm,
        SPAWN.Pool(WORKERS) as pool,
    ):
        episodes = Path(scratch) / "pool" / "episodes"
        episodes.mkdir(parents=True)
        farm_round(farm, warm_up, "warm")
        pool_round(pool, warm_up, episodes, "warm")
        for index in range(rounds):
            outcome.farm.append(farm_round(farm, specs, f"r{index}"))
            outcome.pool.append(pool_round(pool, specs, episodes, f"r{index}"))
            print(
                f"  round {index + 1}/{rounds}: farm {outcome.farm[-1]:.1f} episodes/s, "
                f"pool {outcome.pool[-1]:.1f} episodes/s",
                flush=True,
            )
        outcome.duplicates = farm.duplicates
    return outcome


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--quick", is_flag=True, help="a smoke run of under a minute")
@click.option(
    "--episodes", type=click.IntRange(min=1), help="per round  [default: 40; --quick: 10]"
)
@click.option(
    "--duration",
    type=click.FloatRange(min=0, min_open=True),
    default=5.0,
    show_default=True,
    help="s per episode",
)
@click.option(
    "--rounds",
    type=click.IntRange(min=1),
    help="farm and pool rounds  [default: 5; --quick: 1]",
)
def main(quick: bool, episodes: int | None, duration: float, rounds: int | None) -> None:
    episodes = episodes or (10 if quick else 40)
    rounds = rounds or (1 if quick else 5)
    print(f"farm efficiency: {episodes} x {duration:g} s episodes", flush=True)
    farm = efficiency(episodes, duration, rounds)
    print(f"  {farm.duplicates} duplicate results")
    print()
    print(
        f"farm efficiency ({WORKERS} workers vs Pool({WORKERS}), {episodes} x "
        f"{duration:g} s episodes, medians of {rounds} alternating rounds): {farm.ratio:.2f}"
    )


if __name__ == "__main__":
    main()
