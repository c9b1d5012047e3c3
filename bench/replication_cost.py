"""What validation by replication costs a default run, in one run of this script.

    python bench/replication_cost.py [--pop 30] [--generations 8] [--workers 2] [--seed 0]

The default run's configuration (`analytic start`: a 5 s spiral, the given population) is tuned
twice on one local farm of `--workers` workers: with validation (the default on a farm of two or
more) and without (`--no-replicate`). Printed for each: evaluations, the extra evaluations the
replicas and tie-breaks cost (as a share of the run's own), disagreements, wall time, and the
ratio of the two wall times. Both runs must reach the same front: an honest farm's replicas agree
bit for bit, so validation changes what a run costs, never what it finds.
"""

import tempfile
import time
from pathlib import Path

import click
from common import print_table

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import TuningRun


def tune(endpoint: str, config: RunConfig, directory: Path) -> tuple[TuningRun, float]:
    started = time.perf_counter()
    with (
        TuningRun.create(directory, config) as run,
        FarmClient([endpoint], directory.name, directory) as farm,
    ):
        run.run(farm)
    return run, time.perf_counter() - started


@click.command()
@click.option("--pop", type=click.IntRange(min=4), default=30, show_default=True)
@click.option("--generations", type=click.IntRange(min=1), default=8, show_default=True)
@click.option("--workers", type=click.IntRange(min=2), default=2, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
def main(pop: int, generations: int, workers: int, seed: int) -> None:
    config = RunConfig(pop=pop, generations=generations, seed=seed)
    rows = []
    fronts = []
    with tempfile.TemporaryDirectory() as scratch, local_farm(workers) as endpoint:
        # A generation first, unmeasured: workers build and cache the spiral's reference.
        tune(endpoint, config.model_copy(update={"generations": 1}), Path(scratch) / "warm-up")
        walls = {}
        for replicate in (True, False):
            name = "validated" if replicate else "unvalidated"
            chosen = config.model_copy(update={"replicate": replicate})
            run, wall = tune(endpoint, chosen, Path(scratch) / name)
            walls[name] = wall
            fronts.append([member.objectives for member in run.front()])
            ledger = run.replication
            evaluations = run.state.evolution.evaluations
            rows.append(
                [
                    name,
                    str(evaluations),
                    f"{ledger.refereed} ({ledger.refereed / evaluations:.1%})",
                    str(ledger.disagreements),
                    f"{wall:.1f}",
                ]
            )
    print(f"pop {pop}, {generations} generations, 5 s spiral, {workers} workers, seed {seed}")
    print_table(["run", "evaluations", "refereed here", "disagreements", "wall s"], "lrrrr", rows)
    print(f"wall time, validated / unvalidated: {walls['validated'] / walls['unvalidated']:.2f}")
    print(f"same front: {fronts[0] == fronts[1]}")
    if fronts[0] != fronts[1]:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
