"""Generational against steady-state NSGA-II on the same local farm, in one run.

    python bench/evolution_bench.py [--pop 30] [--generations 10] [--workers 2] [--seed 1]

Both modes tune a generic controller (spiral, random and pyramid, 5 s each: three jobs per
candidate, of unequal cost since diverging episodes stop early) with the same population, seed and
evaluation budget, on one local farm. Printed: the hypervolume after each `pop` evaluations with
the wall time it was reached at, and the workers' utilisation (their time on episodes over
workers × wall time). The modes alternate `--rounds` times; the figures are medians.
"""

import argparse
import statistics
import tempfile
from pathlib import Path

from analytic.farm import FarmClient
from analytic.local import local_farm
from analytic.run import RunConfig, TuningRun
from schemas import TrajectorySpec

TRAJECTORIES = tuple(
    TrajectorySpec(kind=kind, duration=5.0) for kind in ("spiral", "random", "pyramid")
)


def tune(endpoint: str, workers: int, config: RunConfig, directory: Path) -> dict[str, object]:
    run = TuningRun.create(directory, config)
    with FarmClient([endpoint], directory.name, directory) as farm:
        run.run(farm)
    history = run.state.history
    wall = history[-1].wall_seconds
    return {
        "evaluations": [row.evaluations for row in history],
        "hypervolume": [row.hypervolume for row in history],
        "wall": [row.wall_seconds for row in history],
        "utilisation": run.state.busy_seconds / (workers * wall),
        "evaluations_per_s": history[-1].evaluations / wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pop", type=int, default=30)
    parser.add_argument("--generations", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=2)
    options = parser.parse_args()
    runs: dict[str, list[dict[str, object]]] = {"generational": [], "steady-state": []}
    with local_farm(options.workers) as endpoint, tempfile.TemporaryDirectory() as scratch:
        for round_number in range(options.rounds):
            for mode in runs:
                config = RunConfig(
                    pop=options.pop,
                    seed=options.seed,
                    trajectories=TRAJECTORIES,
                    generations=options.generations,
                    asynchronous=mode == "steady-state",
                )
                directory = Path(scratch) / f"{mode}-{round_number}"
                runs[mode].append(tune(endpoint, options.workers, config, directory))
                result = runs[mode][-1]
                print(
                    f"round {round_number + 1}, {mode}: hypervolume "
                    f"{result['hypervolume'][-1]:.4f} after {result['evaluations'][-1]} "
                    f"evaluations in {result['wall'][-1]:.1f} s, utilisation "
                    f"{result['utilisation']:.1%}",
                    flush=True,
                )
    print()
    print(
        f"pop {options.pop}, {options.generations} x pop evaluations, {options.workers} workers,"
        f" generic controller on 3 x 5 s trajectories; medians of {options.rounds} rounds"
    )
    print("| evaluations | generational HV | at wall s | steady-state HV | at wall s |")
    print("|---:|---:|---:|---:|---:|")
    generational, steady = runs["generational"], runs["steady-state"]

    def median(results: list[dict[str, object]], key: str, index: int) -> float:
        return statistics.median(result[key][index] for result in results)

    for index, evaluations in enumerate(generational[0]["evaluations"]):
        print(
            f"| {evaluations} | {median(generational, 'hypervolume', index):.4f} | "
            f"{median(generational, 'wall', index):.1f} | "
            f"{median(steady, 'hypervolume', index):.4f} | {median(steady, 'wall', index):.1f} |"
        )
    for mode, results in runs.items():
        utilisation = statistics.median(result["utilisation"] for result in results)
        rate = statistics.median(result["evaluations_per_s"] for result in results)
        print(f"{mode}: worker utilisation {utilisation:.1%}, {rate:.1f} candidates/s")


if __name__ == "__main__":
    main()
