"""Generational against steady-state NSGA-II on the same local farm, in one run.

    python bench/evolution_bench.py [--pop 30] [--generations 10] [--workers 2] [--seed 1]
        [--rounds 2]

Both modes tune a generic controller (spiral, random and pyramid, 5 s each: three jobs per
candidate, of unequal cost since diverging episodes stop early) with the same population, seed and
evaluation budget, on one local farm. Printed: the hypervolume after each `pop` evaluations with
the wall time it was reached at, and the workers' utilisation (their time on episodes over
workers × wall time). The modes alternate `--rounds` times; the figures are medians.
"""

import statistics
import tempfile
from dataclasses import dataclass
from pathlib import Path

import click
from common import print_table

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.schemas import TrajectorySpec

TRAJECTORIES = tuple(
    TrajectorySpec(kind=kind, duration=5.0) for kind in ("spiral", "random", "pyramid")
)
MODES = ("generational", "steady-state")


@dataclass(frozen=True)
class Tuned:
    """One run, from its history: a row per generation (per `pop` evaluations)."""

    evaluations: list[int]
    hypervolume: list[float]
    wall: list[float]  # s from the run's start
    utilisation: float  # the workers' time on its episodes over workers × wall time
    evaluations_per_s: float


def tune(endpoint: str, workers: int, config: RunConfig, directory: Path) -> Tuned:
    run = TuningRun.create(directory, config)
    with FarmClient([endpoint], directory.name, directory) as farm:
        run.run(farm)
    history = run.state.history
    wall = history[-1].wall_seconds
    return Tuned(
        evaluations=[row.evaluations for row in history],
        hypervolume=[row.hypervolume for row in history],
        wall=[row.wall_seconds for row in history],
        utilisation=run.state.busy_seconds / (workers * wall),
        evaluations_per_s=history[-1].evaluations / wall,
    )


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--pop", type=click.IntRange(4, 1000), default=30, show_default=True)
@click.option(
    "--generations",
    type=click.IntRange(min=1),
    default=10,
    show_default=True,
    help="evaluation budget, in generations of pop candidates",
)
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True)
@click.option(
    "--rounds",
    type=click.IntRange(min=1),
    default=2,
    show_default=True,
    help="runs of each mode, alternating",
)
def main(pop: int, generations: int, workers: int, seed: int, rounds: int) -> None:
    runs: dict[str, list[Tuned]] = {mode: [] for mode in MODES}
    with local_farm(workers) as endpoint, tempfile.TemporaryDirectory() as scratch:
        for round_number in range(rounds):
            for mode in MODES:
                config = RunConfig(
                    pop=pop,
                    seed=seed,
                    trajectories=TRAJECTORIES,
                    generations=generations,
                    asynchronous=mode == "steady-state",
                )
                directory = Path(scratch) / f"{mode}-{round_number}"
                result = tune(endpoint, workers, config, directory)
                runs[mode].append(result)
                print(
                    f"round {round_number + 1}, {mode}: hypervolume "
                    f"{result.hypervolume[-1]:.4f} after {result.evaluations[-1]} "
                    f"evaluations in {result.wall[-1]:.1f} s, utilisation "
                    f"{result.utilisation:.1%}",
                    flush=True,
                )
    print()
    print(
        f"pop {pop}, {generations} x pop evaluations, {workers} workers,"
        f" generic controller on 3 x 5 s trajectories; medians of {rounds} rounds"
    )

    def median(mode: str, series: str, index: int) -> float:
        return statistics.median(getattr(result, series)[index] for result in runs[mode])

    rows = []
    for index, evaluations in enumerate(runs[MODES[0]][0].evaluations):
        row = [str(evaluations)]
        for mode in MODES:
            row.append(f"{median(mode, 'hypervolume', index):.4f}")
            row.append(f"{median(mode, 'wall', index):.1f}")
        rows.append(row)
    header = ("evaluations", "generational HV", "at wall s", "steady-state HV", "at wall s")
    print_table(header, "rrrrr", rows)
    for mode, results in runs.items():
        utilisation = statistics.median(result.utilisation for result in results)
        rate = statistics.median(result.evaluations_per_s for result in results)
        print(f"{mode}: worker utilisation {utilisation:.1%}, {rate:.1f} candidates/s")


if __name__ == "__main__":
    main()
