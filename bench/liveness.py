"""What a hoarder and a silent holder cost a run, side by side with the calm run, in one go.

    python bench/liveness.py [--pop 16] [--generations 8] [--seed 7] [--duration 3] \
        [--workers 2] [--lease-seconds 60] [--repeat 3]

The same `analytic start --pop P --generations G --seed S --duration D --connect ...` runs on a
fresh farm (a broker with the farm's own lease, `--workers` honest worker processes) calm, and
with one more worker of each rogue kind (tests/rogue.py): a hoarder (takes batches, runs none,
asks again at once), a holder (sits on the batch it was given) and a silent holder (hands its
results in to the broker, sends them to nobody). The four take turns, `--repeat` rounds, after an
unmeasured one-generation run (the first farm of a session is slower to start). Printed for each,
the median over the rounds: when generation G was reached (the run's own progress line), the wall
time of the whole command, the ratio of each to the calm run's, what the broker saw (leases given
back, copies of overdue jobs) and the results taken from the broker's records; and whether every
front is the calm run's (it must be: generational NSGA-II is deterministic given the values it is
told, and a rogue that only delays changes none of them).
"""

import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import click
from common import loopback_endpoint, print_table

from gainfarm.analytic.evaluators.local import spawn_worker, stop_workers
from gainfarm.broker.service import Broker

ROOT = Path(__file__).resolve().parents[1]  # where `python -m tests.rogue` runs
KINDS = ("calm", "hoarder", "holder", "silent")
MEASURED = ("last", "wall", "abandoned", "copies", "unheard")


def run(kind: str, arguments: list[str], workers: int, lease: float, out: Path) -> dict:
    endpoint = loopback_endpoint()
    with Broker([endpoint], lease_seconds=lease) as broker:
        processes = [spawn_worker(endpoint, f"honest-{n}") for n in range(workers)]
        if kind != "calm":
            processes.append(
                subprocess.Popen(
                    [sys.executable, "-m", "tests.rogue", kind, endpoint, kind],
                    cwd=ROOT,
                    stdin=subprocess.DEVNULL,
                )
            )
        try:
            give_up = time.monotonic() + 60
            while broker.queue.worker_count() < len(processes):
                if time.monotonic() > give_up:
                    raise SystemExit("the workers did not join")
                time.sleep(0.1)
            started = time.perf_counter()
            command = ["start", *arguments, "--connect", endpoint, "--out", str(out)]
            ran = subprocess.run(
                [sys.executable, "-m", "gainfarm.analytic", *command],
                capture_output=True,
                text=True,
            )
            wall = time.perf_counter() - started
        finally:
            stop_workers(processes)
    if ran.returncode != 0:
        raise SystemExit(f"{kind}: analytic start failed:\n{ran.stderr[-2000:]}")
    output = ran.stdout + ran.stderr
    reached = re.findall(r"generation \d+: \d+ evaluations in ([\d.]+) s", output)
    return {
        "last": float(reached[-1]),
        "wall": wall,
        "front": (out / "front.csv").read_bytes(),
        "abandoned": broker.queue.abandoned,
        "copies": broker.queue.copies,
        "unheard": output.count("taken from the broker's record"),
    }


@click.command()
@click.option("--pop", type=click.IntRange(min=4), default=16, show_default=True)
@click.option("--generations", type=click.IntRange(min=1), default=8, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=7, show_default=True)
@click.option("--duration", type=float, default=3.0, show_default=True)
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--lease-seconds", type=float, default=60.0, show_default=True)
@click.option("--repeat", type=click.IntRange(min=1), default=3, show_default=True)
def main(
    pop: int,
    generations: int,
    seed: int,
    duration: float,
    workers: int,
    lease_seconds: float,
    repeat: int,
) -> None:
    arguments = ["--pop", str(pop), "--seed", str(seed), "--duration", str(duration)]
    runs: dict[str, list[dict]] = {kind: [] for kind in KINDS}
    with tempfile.TemporaryDirectory() as scratch:
        warm = [*arguments, "--generations", "1"]
        run("calm", warm, workers, lease_seconds, Path(scratch) / "warm-up")
        arguments += ["--generations", str(generations)]
        for round_ in range(repeat):
            for kind in KINDS:
                out = Path(scratch) / f"{kind}-{round_}"
                runs[kind].append(run(kind, arguments, workers, lease_seconds, out))
    calm_front = runs["calm"][0]["front"]
    median = {
        kind: {key: statistics.median(r[key] for r in done) for key in MEASURED}
        for kind, done in runs.items()
    }
    calm = median["calm"]
    rows = [
        [
            kind,
            f"{m['last']:.1f}",
            f"{m['last'] / calm['last']:.2f}",
            f"{m['wall']:.1f}",
            f"{m['wall'] / calm['wall']:.2f}",
            f"{m['abandoned']:g}",
            f"{m['copies']:g}",
            f"{m['unheard']:g}",
            "yes" if all(r["front"] == calm_front for r in runs[kind]) else "NO",
        ]
        for kind, m in median.items()
    ]
    print(
        f"analytic start {' '.join(arguments)} --connect: {workers} honest workers "
        f"(+ the rogue), lease {lease_seconds:g} s; medians of {repeat} rounds"
    )
    header = ["run", f"generation {generations} at, s", "x calm", "wall s", "x calm"]
    header += ["leases given back", "copies", "results from records", "calm front"]
    print_table(header, "lrrrrrrrl", rows)
    if any(r["front"] != calm_front for done in runs.values() for r in done):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
