"""Optuna's TPE asked a generation at a time against TPE told one result at a time (--async), on
the default problem, through the command a user types.

    python bench/tpe_async.py [--evaluations 300] [--seeds 3] [--workers 2]
        [--modes tpe,tpe-async,random,nsga2] [--out DIR]

Each mode is `analytic start --algorithm A [--async] --evaluations N --seed S --local --workers W
--check-plants 0` (the default problem: the 5 s spiral on the realistic FRI plant, population 30),
one run per seed, the modes interleaved seed by seed. From each run's evaluated.csv (the order
told), the hypervolume of the feasible points among its first k evaluations, at k = 100, 200,
... and N: the run's own measure (analytic.tuning.evolution.hypervolume: the fixed reference
point, f_t on a log scale), and the algorithms experiment's (normalised between the ideal and the
nadir of every run's front pooled). Printed: each run's line, then the medians per mode with the
best error and the runs' own wall time (history.csv: on a shared machine, a measure of the load
as much as of the mode). A run directory is kept (under --out) and reused when the bench is run
again with the same settings.
"""

import statistics
import subprocess
import sys
from pathlib import Path

import click
from common import print_table

from gainfarm.analytic.experiments import normalisation as normalised
from gainfarm.analytic.experiments.algorithms_measures import feasible, hypervolume_curve
from gainfarm.analytic.experiments.normalisation import Normalisation
from gainfarm.analytic.tuning.evolution import hypervolume
from gainfarm.analytic.tuning.records import RunRecord, read_run

MODES = {
    "tpe": ("--algorithm", "tpe"),
    "tpe-async": ("--algorithm", "tpe", "--async"),
    "random": ("--algorithm", "random"),
    "nsga2": ("--algorithm", "nsga2"),
}
STEP = 100  # evaluations between the hypervolumes printed


def curve(run: RunRecord, at: list[int], normalisation: Normalisation | None = None) -> list[float]:
    """The hypervolume of the feasible points among the run's first k evaluations, for k in
    `at`: in the run's own fixed box, or in `normalisation` (the experiment's space)."""
    kept = feasible(run)
    if normalisation is not None:
        return hypervolume_curve(run.evaluated, at, normalisation, kept=kept)
    return [
        hypervolume([p for p, ok in zip(run.evaluated[:k], kept[:k], strict=True) if ok])
        for k in at
    ]


def medians(rows: dict[str, list[list[float]]], mode: str, count: int) -> list[str]:
    return [f"{statistics.median(c[index] for c in rows[mode]):.4f}" for index in range(count)]


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
    runs: dict[str, list[RunRecord]] = {mode: [] for mode in chosen}
    for seed in range(seeds):
        for mode in chosen:
            directory = out / f"{mode}-e{evaluations}-s{seed}"
            if not (directory / "report.md").exists():
                command = [
                    *(sys.executable, "-m", "gainfarm.analytic", "start"),
                    *MODES[mode],
                    *("--evaluations", str(evaluations), "--seed", str(seed)),
                    *("--local", "--workers", str(workers), "--check-plants", "0"),
                    *("--out", str(directory)),
                ]
                subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
            runs[mode].append(read_run(directory))
            values = ", ".join(f"{value:.4f}" for value in curve(runs[mode][-1], at))
            print(f"{mode}, seed {seed}: hypervolume at {at}: {values}", flush=True)
    # The experiment's measure too: every run's feasible front pooled into one normalised space
    # (analytic.experiments.normalisation), where the fixed box's 0.96-0.99 spread out.
    normalisation = Normalisation.of(
        [[m.objectives for m in run.front] for mode in chosen for run in runs[mode]]
    )
    fixed = {mode: [curve(run, at) for run in runs[mode]] for mode in chosen}
    pooled = {mode: [curve(run, at, normalisation) for run in runs[mode]] for mode in chosen}
    # The experiments floor f_t at 10⁻² (N·m)² (normalisation.F_T_FLOOR), inside the FRI plant's
    # fronts: the same measure without the floor, so that the smooth end below it counts too.
    floor, normalised.F_T_FLOOR = normalised.F_T_FLOOR, 1e-12
    unfloored = {mode: [curve(run, at, normalisation) for run in runs[mode]] for mode in chosen}
    normalised.F_T_FLOOR = floor
    best = {
        mode: statistics.median(min(m.objectives[0] for m in r.front) * 1000 for r in runs[mode])
        for mode in chosen
    }
    print()
    print(
        f"default problem (5 s spiral, realistic FRI plant, population 30), {evaluations} "
        f"evaluations, {workers} local workers; medians of {seeds} seeds. HV: the run's own "
        "(fixed reference point); pooled: normalised over every run's front (f_acc "
        f"{normalisation.ideal[0] * 1000:.2f}-{normalisation.nadir[0] * 1000:.2f} mm, f_t "
        f"{normalisation.ideal[1]:.3g}-{normalisation.nadir[1]:.3g} (N·m)², log)"
    )
    rows = [
        [
            mode,
            *medians(fixed, mode, len(at)),
            *medians(pooled, mode, len(at)),
            *medians(unfloored, mode, len(at)),
            f"{best[mode]:.3f}",
            f"{statistics.median(run.wall_seconds for run in runs[mode]):.0f}",
        ]
        for mode in chosen
    ]
    header = [
        "mode",
        *(f"HV at {k}" for k in at),
        *(f"pooled HV at {k}" for k in at),
        *(f"unfloored at {k}" for k in at),
        "best error mm",
        "wall s",
    ]
    print_table(header, "l" + "r" * (len(header) - 1), rows)


if __name__ == "__main__":
    main()
