"""Each process's peak memory under junk on every key it serves, against the same process's calm
peak in the same configuration, in one run of this script (issue 47, item 4).

    python bench/key_flood.py [--pop 8] [--generations 2] [--workers 2] [--put-mib 64]
        [--ask-mib 250]

Two runs of the default run's configuration (`analytic start`: a 5 s spiral, `--keep front`)
with the same seed, each on a fresh farm: a broker process, `--workers` worker processes and the
analytic process. The first is calm. In the second, from before the run starts to its end,
tests/analytic/flooder.py puts `--put-mib` MiB samples on every key the three processes
subscribe to (the study's results; the liveliness keys, which a put reaches as far as the
router) and, from a flooder process of its own, asks with `--ask-mib` MiB payloads on every key
they serve (the broker's submit, lease, confirm and status; each worker's log keys; the analytic's
model key). Printed: each process's peak RSS (VmHWM; a worker's is the largest of theirs) in
both runs and their ratio, what the flooders sent and the answers they got; both runs must reach
the same front.
"""

import multiprocessing
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import click
from common import SPAWN, loopback_endpoint, print_table
from flood_memory import analytic

from gainfarm.analytic.evaluators.local import spawn_broker, spawn_worker, stop_workers
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.schemas import keys

ROOT = Path(__file__).resolve().parent.parent  # where `python -m tests.analytic.flooder` runs
MIB = 1024 * 1024


def peak_mib(pid: int) -> float:
    """A live process's peak resident memory (VmHWM), MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmHWM for process {pid}")


@contextmanager
def flooding(endpoint: str, mib: int, option: str, flooded: Sequence[str]) -> Iterator[list[str]]:
    """The flooder putting (`--put`) or asking (`--ask`) on `flooded`; its last line at the end."""
    command = ["-m", "tests.analytic.flooder", endpoint, "-", "--mib", str(mib)]
    command += [f"{option}={key}" for key in flooded]
    flooder = subprocess.Popen(
        [sys.executable, *command], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    assert flooder.stdout is not None and flooder.stdout.readline() == "flooding\n"
    said: list[str] = []
    try:
        yield said
    finally:
        flooder.terminate()
        said.append(flooder.communicate(timeout=60)[0].strip())


def put_keys(study: str) -> list[str]:
    """Every key the three processes subscribe to."""
    return [keys.result(study, "junk"), keys.ALIVE_BROKER, keys.alive_study(study)]


def ask_keys(study: str, workers: Sequence[str]) -> list[str]:
    """Every key the three processes serve."""
    served = [keys.submit(study), keys.lease(workers[0]), keys.confirm(study), keys.STATUS]
    served += [keys.log(study, worker, "0" * 64) for worker in workers]
    return [*served, keys.model(study, "0" * 64)]


def measure(
    config: RunConfig, workers: int, directory: Path, flood: tuple[int, int] | None
) -> tuple[dict[str, float], float, str, list[str]]:
    """One run on a fresh farm: the peak of each process, the wall time, the front and what
    the flooders said."""
    endpoint = loopback_endpoint()
    study = "flooded" if flood else "calm"
    names = [f"cobot-{n}" for n in range(workers)]
    broker = spawn_broker(endpoint)
    time.sleep(3.0)  # the broker's router listens; the FarmClient waits for its answer
    farm = [spawn_worker(endpoint, name, "warning") for name in names]
    said: list[list[str]] = []
    try:
        out: multiprocessing.Queue = SPAWN.Queue()
        run = SPAWN.Process(target=analytic, args=(endpoint, study, directory, config, None, out))
        if flood is None:
            run.start()
            figures = out.get()
        else:
            put_mib, ask_mib = flood
            with (
                flooding(endpoint, put_mib, "--put", put_keys(study)) as puts,
                flooding(endpoint, ask_mib, "--ask", ask_keys(study, names)) as asks,
            ):
                said += [puts, asks]
                run.start()
                figures = out.get()
        run.join()
        peaks = {
            "analytic": figures[0],
            "broker": peak_mib(broker.pid),
            "worker": max(peak_mib(worker.pid) for worker in farm),
        }
    finally:
        stop_workers(farm)
        broker.terminate()
        broker.wait(30)
    return peaks, figures[1], figures[5], [line for lines in said for line in lines]


@click.command()
@click.option("--pop", type=click.IntRange(min=4), default=8, show_default=True)
@click.option("--generations", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--put-mib", type=click.IntRange(min=1), default=64, show_default=True)
@click.option("--ask-mib", type=click.IntRange(min=1), default=250, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
def main(pop: int, generations: int, workers: int, put_mib: int, ask_mib: int, seed: int) -> None:
    config = RunConfig(pop=pop, generations=generations, seed=seed)
    with tempfile.TemporaryDirectory() as scratch:
        calm, calm_wall, calm_front, _ = measure(config, workers, Path(scratch) / "calm", None)
        flooded, wall, front, said = measure(
            config, workers, Path(scratch) / "flooded", (put_mib, ask_mib)
        )
    print(f"plain profile, --keep front; pop {pop}, {generations} generations, {workers} workers")
    print(f"flood: {put_mib} MiB puts on every key subscribed, {ask_mib} MiB queries on every key")
    print(f"served; wall {calm_wall:.1f} s calm, {wall:.1f} s flooded")
    rows = [
        [name, f"{calm[name]:.0f}", f"{flooded[name]:.0f}", f"{flooded[name] / calm[name]:.2f}x"]
        for name in calm
    ]
    print_table(["process", "calm peak MiB", "flooded peak MiB", "ratio"], "lrrr", rows)
    print(f"puts: {said[0]}; queries: {said[1]}")
    same = front == calm_front
    print(f"same front: {same}")
    if not same:
        sys.exit(1)


if __name__ == "__main__":
    main()
