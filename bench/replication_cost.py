"""What validation by the referee costs a default run, in one run of this script.

    python bench/replication_cost.py [--pop 30] [--generations 8] [--workers 2 --workers 8]
                                     [--seed 0]

The default run's configuration (`analytic start`: a 5 s spiral, the given population) is tuned
three times on each local farm of `--workers` workers, connected to as a farm (so refereed): not
validated (`--no-replicate`), the front alone refereed (`--spot-checks 0`), and the front with spot
checks at 0.05 (the former default; the default now sizes the rate: docs/security.md). Printed for
each: evaluations, the episodes the referee ran again (the front's, the spot checks') as a share of
the run's, its time per evaluation against the workers' (simulating and encoding each episode),
disagreements, wall time and its ratio to the unvalidated run's. Every run must reach the same
front: an honest farm agrees with the referee bit for bit, so validation changes what a run costs,
never what it finds.
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

SETTINGS = {
    "not validated": {"replicate": False},
    "front only": {"spot_checks": 0.0},
    "front and spot checks": {"spot_checks": 0.05},
}


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
@click.option(
    "--workers", type=click.IntRange(min=2), multiple=True, default=(2, 8), show_default=True
)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
def main(pop: int, generations: int, workers: tuple[int, ...], seed: int) -> None:
    config = RunConfig(pop=pop, generations=generations, seed=seed)
    rows = []
    fronts = []
    for count in workers:
        with tempfile.TemporaryDirectory() as scratch, local_farm(count) as endpoint:
            # A generation first, unmeasured: workers build and cache the spiral's reference.
            warm_up = config.model_copy(update={"generations": 1})
            tune(endpoint, warm_up, Path(scratch) / "warm-up")
            plain = None
            for name, update in SETTINGS.items():
                chosen = config.model_copy(update=update)
                run, wall = tune(endpoint, chosen, Path(scratch) / name.replace(" ", "-"))
                plain = plain or wall
                fronts.append([member.objectives for member in run.front()])
                ledger = run.replication
                evaluations = run.state.evolution.evaluations
                busy = run.state.busy_seconds / evaluations
                rows.append(
                    [
                        str(count),
                        name,
                        str(evaluations),
                        f"{ledger.refereed} ({ledger.refereed / evaluations:.1%})",
                        f"{ledger.spot_checked} ({ledger.spot_checked / evaluations:.1%})",
                        f"{1000 * ledger.seconds / evaluations:.1f}",
                        f"{1000 * busy:.1f}",
                        str(ledger.disagreements),
                        f"{wall:.1f}",
                        f"{wall / plain:.2f}",
                    ]
                )
    print(f"pop {pop}, {generations} generations, 5 s spiral, seed {seed}")
    print_table(
        [
            "workers",
            "run",
            "evaluations",
            "front refereed",
            "spot-checked",
            "referee ms/eval",
            "workers ms/eval",
            "disagreements",
            "wall s",
            "vs not validated",
        ],
        "rlrrrrrrrr",
        rows,
    )
    same = all(front == fronts[0] for front in fronts)
    print(f"same front in every run: {same}")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
