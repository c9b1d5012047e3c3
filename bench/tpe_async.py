"""Optuna's TPE asked a generation at a time against TPE told one result at a time (--async), on
the default problem, through the command a user types.

    python bench/tpe_async.py [--evaluations 300] [--seeds 3] [--workers 2]
        [--modes tpe,tpe-async,random,nsga2] [--out DIR]

Each mode is `analytic start --algorithm A [--async] --evaluations N --seed S --local --workers W
--check-plants 0` (the default problem: the 5 s spiral on the realistic FRI plant, population 30),
one run per seed, the modes interleaved seed by seed. From each run's evaluated.csv (the order
told), the hypervolume of the feasible points among its first k evaluations (the run's own
measure: analytic.tuning.evolution.hypervolume, the fixed reference point, f_t on a log scale), at
k = 100, 200, ... and N. Printed: each run's line, then the medians per mode. A run directory is
kept (under --out) and reused when the bench is run again with the same settings.
"""

import statistics
import subprocess
import sys
import time
from pathlib import Path

import click
from common import print_table

from gainfarm.analytic.tuning.evolution import hypervolume
from gainfarm.analytic.tuning.records import read_run

MODES = {
    "tpe": ("--algorithm", "tpe"),
    "tpe-async": ("--algorithm", "tpe", "--async"),
    "random": ("--algorithm", "random"),
    "nsga2": ("--algorithm", "nsga2"),
}
STEP = 100  # evaluations between the hypervolumes printed


def curve(directory: Path, at: list[int]) -> list[float]:
    """The hypervolume of the feasible points among the run's first k evaluations, for k in
    `at`."""
    run = read_run(directory)
    kept = [not run.config.limits.violated(measures) for measures in run.measured]
    return [
        hypervolume([p for p, ok in zip(run.evaluated[:k], kept[:k], strict=True) if ok])
        for k in at
    ]


@click.command()
@click.option("--evaluations", type=click.IntRange(min=60), default=300, show_default=True)
@click.option("--seeds", type=click.IntRange(min=1), default=3, show_default=True)
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--modes", default=",".join(MODES), show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("bench-tpe-async"))
def main(evaluations: int, seeds: int, workers: int, modes: str, out: Path) -> None:
    chosen = [mode.strip() for mode in modes.split(",")]
    for mode in chosen:
        if mode not in MODES:
            raise click.BadParameter(f"{mode!r}: one of {', '.join(MODES)}", param_hint="--modes")
    at = [*range(STEP, evaluations, STEP), evaluations]
    curves: dict[str, list[list[float]]] = {mode: [] for mode in chosen}
    walls: dict[str, list[float]] = {mode: [] for mode in chosen}
    for seed in range(seeds):
        for mode in chosen:
            directory = out / f"{mode}-e{evaluations}-s{seed}"
            started = time.monotonic()
            if not (directory / "report.md").exists():
                command = [
                    *(sys.executable, "-m", "gainfarm.analytic", "start"),
                    *MODES[mode],
                    *("--evaluations", str(evaluations), "--seed", str(seed)),
                    *("--local", "--workers", str(workers), "--check-plants", "0"),
                    *("--out", str(directory)),
                ]
                subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
            walls[mode].append(time.monotonic() - started)
            curves[mode].append(curve(directory, at))
            values = ", ".join(f"{value:.4f}" for value in curves[mode][-1])
            print(f"{mode}, seed {seed}: hypervolume at {at}: {values}", flush=True)
    print()
    print(
        f"default problem (5 s spiral, realistic FRI plant, population 30), {evaluations} "
        f"evaluations, {workers} local workers; medians of {seeds} seeds"
    )
    rows = [
        [mode]
        + [f"{statistics.median(c[index] for c in curves[mode]):.4f}" for index in range(len(at))]
        + [f"{statistics.median(walls[mode]):.0f}"]
        for mode in chosen
    ]
    header = ["mode", *(f"HV at {k}" for k in at), "wall s"]
    print_table(header, "l" + "r" * (len(header) - 1), rows)


if __name__ == "__main__":
    main()
