"""How well a converging run's time left is estimated: the estimate made along finished runs,
against when each actually stopped.

Run from bench/: `python time_left.py RUN [RUN ...]`, each a run directory that stopped on
convergence (the default: no --generations or --evaluations). For every generation of a run at
which an estimate is given (analytic.tuning.termination.expected_generations on the hypervolumes
so far), the generations it says are left are compared with those that were; the same at the
run's halfway point. Prints, over all runs: how many estimates, the median ratio of the
estimated to the actual generations left (above 1: too long), its 10th and 90th percentiles, and
the share within a factor of 2. The figures go in docs/tuning.md.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

from gainfarm.analytic.tuning.records import HISTORY_CSV, read_history, read_run
from gainfarm.analytic.tuning.termination import expected_generations


def ratios(directory: Path) -> tuple[list[float], float | None, int]:
    """A run's estimates of the generations left over the actual ones, at every generation and
    at its halfway point, and its generations."""
    record = read_run(directory)
    hypervolumes = [row.hypervolume for row in read_history(directory / HISTORY_CSV)]
    stop = len(hypervolumes)
    if record.config.termination.reason(hypervolumes, record.evaluations) is None:
        raise SystemExit(f"{directory}: did not stop on convergence")
    found: dict[int, float] = {}
    for now in range(1, stop):
        expected = expected_generations(record.config.termination, hypervolumes[:now])
        if expected is not None:
            found[now] = (expected - now) / (stop - now)
    halfway = found.get(stop // 2)
    return list(found.values()), halfway, stop


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    runs = parser.parse_args().runs
    every: list[float] = []
    halfway: list[float] = []
    for directory in runs:
        found, middle, stop = ratios(directory)
        every += found
        if middle is not None:
            halfway.append(middle)
        middle_text = "none" if middle is None else f"{middle:.2f}×"
        print(f"{directory}: stopped after {stop} generations; halfway estimate {middle_text}")
    for name, values in (("every generation", every), ("halfway", halfway)):
        if not values:
            print(f"{name}: no estimate")
            continue
        array = np.asarray(values)
        low, high = np.percentile(array, [10, 90])
        within = np.mean((array >= 0.5) & (array <= 2.0))
        print(
            f"{name}: {len(array)} estimates; estimated over actual generations left: median "
            f"{np.median(array):.2f}×, 10th-90th percentile {low:.2f}×-{high:.2f}×; within a "
            f"factor of 2: {within:.0%} (over {len(runs)} runs)"
        )


if __name__ == "__main__":
    sys.exit(main())
