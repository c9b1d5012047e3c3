"""The paper's whole campaign on one machine: its three experiments, 5 repetitions each,
population 30 (population sizes 10-80 in the population-size experiment), every run to
convergence.

    python bench/campaign.py [--out campaign] [--workers 2] [--reps 5] [--plant realistic|ideal]

Runs each experiment as its command line (`analytic experiment ...`) in turn, on a local farm,
and prints the wall time of each and of the whole; the reports are in OUT/<experiment>/report.md.
"""

import subprocess
import sys
import time
from pathlib import Path

import click

EXPERIMENTS = {
    "popsize": ["--sizes", "10,20,30,50,80"],
    "generic-vs-specific": [],
    "speed": ["--durations", "3,4,5,6"],
}


@click.command(help=__doc__.split("\n\n")[0])
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("campaign"),
    show_default=True,
    help="one directory per experiment in it (an existing one is resumed)",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=2,
    show_default=True,
    help="local worker processes",
)
@click.option(
    "--reps",
    type=click.IntRange(min=1),
    default=5,
    show_default=True,
    help="repetitions per experiment",
)
@click.option(
    "--plant",
    type=click.Choice(["realistic", "ideal"]),
    default="realistic",
    show_default=True,
    help="the simulated plant (ideal: the paper's, as the first wave ran it)",
)
def main(out: Path, workers: int, reps: int, plant: str) -> None:
    walls: dict[str, float] = {}
    for name, extra in EXPERIMENTS.items():
        started = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-m",
                "analytic",
                "experiment",
                name,
                "--reps",
                str(reps),
                "--workers",
                str(workers),
                "--out",
                str(out / name),
                "--plant",
                plant,
                *extra,
            ],
            check=True,
        )
        walls[name] = time.perf_counter() - started
        print(f"{name}: {walls[name] / 60:.1f} min", flush=True)
    print(f"whole campaign: {sum(walls.values()) / 60:.1f} min on {workers} workers")


if __name__ == "__main__":
    main()
