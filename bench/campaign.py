"""The paper's whole campaign on one machine: the three studies, 5 repetitions each, population
30 (population sizes 10-80 in the population study), every run to convergence.

    python bench/campaign.py [--out campaign] [--workers 2] [--reps 5]

Runs each study as its command line (`analytic experiment ...`) in turn, prints the wall time of
each and of the whole; the studies' reports are in OUT/<study>/report.md.
"""

import argparse
import subprocess
import sys
import time
from pathlib import Path

STUDIES = {
    "popsize": ["--sizes", "10,20,30,50,80"],
    "generic-vs-specific": [],
    "speed": ["--durations", "3,4,5,6"],
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("campaign"))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--reps", type=int, default=5)
    options = parser.parse_args()
    walls = {}
    for name, extra in STUDIES.items():
        started = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-m",
                "analytic",
                "experiment",
                name,
                "--reps",
                str(options.reps),
                "--workers",
                str(options.workers),
                "--out",
                str(options.out / name),
                *extra,
            ],
            check=True,
        )
        walls[name] = time.perf_counter() - started
        print(f"{name}: {walls[name] / 60:.1f} min", flush=True)
    print(f"whole campaign: {sum(walls.values()) / 60:.1f} min on {options.workers} workers")


if __name__ == "__main__":
    main()
