"""How well a converging run's time left is estimated: the estimate made along finished runs,
against when each actually stopped, and beside two guesses that need no fit.

Run from bench/: `python time_left.py RUN [RUN ...]`, each a run directory that stopped on
convergence (the default: no --generations or --evaluations). At every generation of a run at
which an estimate is given (analytic.tuning.termination.expected_generations on the hypervolumes
so far), the generations it says are left are compared with those that were. The same for two
plain guesses from the same generations on: one more window of the rule ("+window"), and as
many generations again as have passed ("as long again"). Prints, for each, over all runs: how
many estimates, the median ratio of the estimated to the actual generations left (above 1: too
long), its 10th and 90th percentiles, and the share within a factor of 2. The figures go in
docs/tuning.md.
"""

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gainfarm.analytic.tuning.records import HISTORY_CSV, read_history, read_run
from gainfarm.analytic.tuning.termination import (
    ESTIMATE_AFTER,
    Termination,
    expected_generations,
)

Estimator = Callable[[Termination, list[float]], int | None]
ESTIMATORS: dict[str, Estimator] = {
    "the fit": expected_generations,
    "+window": lambda rule, h: (
        max(len(h), rule.window) + rule.window if len(h) >= ESTIMATE_AFTER else None
    ),
    "as long again": lambda rule, h: (
        max(2 * len(h), rule.window + 1) if len(h) >= ESTIMATE_AFTER else None
    ),
}


def ratios(directory: Path, estimator: Estimator) -> list[float]:
    """A run's estimates of the generations left over the actual ones, at every generation."""
    record = read_run(directory)
    hypervolumes = [row.hypervolume for row in read_history(directory / HISTORY_CSV)]
    stop = len(hypervolumes)
    rule = record.config.termination
    if rule.reason(hypervolumes, record.evaluations) is None:
        raise ValueError("it did not stop on convergence")
    found = []
    for now in range(1, stop):
        expected = estimator(rule, hypervolumes[:now])
        if expected is not None:
            found.append((expected - now) / (stop - now))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    runs = []
    for directory in parser.parse_args().runs:
        try:
            ratios(directory, ESTIMATORS["the fit"])
        except (OSError, ValueError) as error:  # never finished a generation, or not converged
            print(f"{directory}: skipped: {error}")
            continue
        runs.append(directory)
    for name, estimator in ESTIMATORS.items():
        array = np.asarray([r for directory in runs for r in ratios(directory, estimator)])
        if not len(array):
            print(f"{name}: no estimate")
            continue
        low, high = np.percentile(array, [10, 90])
        within = np.mean((array >= 0.5) & (array <= 2.0))
        print(
            f"{name}: {len(array)} estimates over {len(runs)} runs; estimated over actual "
            f"generations left: median {np.median(array):.2f}×, 10th-90th percentile "
            f"{low:.2f}×-{high:.2f}×; within a factor of 2: {within:.0%}"
        )


if __name__ == "__main__":
    sys.exit(main())
