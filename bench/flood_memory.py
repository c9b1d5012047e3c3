"""The analytic process's peak memory under a flood of junk on its study's result keys, against a
calm run of the same configuration, in one run of this script (issue 28, item 5).

    python bench/flood_memory.py [--pop 8] [--generations 2] [--workers 2] [--mib 64] [--tls]
        [--keep front|all]

A broker process and `--workers` worker processes serve two runs of the default run's
configuration (`analytic start`: a 5 s spiral) with the same seed, each in a fresh analytic
process: calm; with tests/analytic/flooder.py putting `--mib` MiB samples of junk on the study's
result keys from before the run starts to its end (no Result, a garbage one, another study's);
and with every other sample a well-formed forgery for a job id the run is likely to have pending,
which the client holds until the broker says it did not take it. With `--tls`, the secure
profile: the flooder holds a worker certificate and no lease. With `--keep all` every log is
fetched from its worker once its result is confirmed, as in a `--keep all` run (the default,
`front`, fetches the front's alone); either way no result carries a log, and the client's session
takes no message larger than a wire message. Printed for each: the
analytic's peak RSS (VmHWM), wall time, samples put, what the client dropped, its peak of held
bytes, and the ratio of the peaks; every run must reach the same front.
"""

import multiprocessing
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import click
from common import SPAWN, loopback_endpoint, print_table

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import spawn_worker, stop_workers
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.broker.certs import write_dev_credentials
from gainfarm.schemas.security import TlsIdentity

ROOT = Path(__file__).resolve().parent.parent  # where `python -m tests.analytic.flooder` runs
MIB = 1024 * 1024


def analytic(
    endpoint: str, study: str, directory: Path, config: RunConfig, tls: Path | None, out
) -> None:
    """One run in this (fresh) process; its figures go to `out`."""
    identity = TlsIdentity(tls, "analytic", "alice") if tls else None
    waits: list[str | None] = []
    started = time.perf_counter()
    with (
        TuningRun.create(directory, config) as run,
        FarmClient(
            [endpoint], study, directory, identity=identity, keep_logs=config.keep == "all"
        ) as farm,
    ):
        farm.on_wait = waits.append
        run.run(farm)
        counts = (farm.ignored, farm.duplicates, farm.unconfirmed, farm.dropped)
        peak_held = farm.peak_held_bytes
    wall = time.perf_counter() - started
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    front = (directory / "front.csv").read_text()
    out.put((peak_rss, wall, counts, peak_held, len([w for w in waits if w]), front))


def measure(
    endpoint: str,
    study: str,
    directory: Path,
    config: RunConfig,
    tls: Path | None,
    flood_mib: int | None,
    forge: bool = True,
) -> tuple:
    flooder = None
    if flood_mib is not None:
        who = ["--tls", str(tls), "--name", "flooder"] if tls else []
        who += [] if forge else ["--junk-only"]
        command = ["-m", "tests.analytic.flooder", endpoint, study, "--mib", str(flood_mib)]
        flooder = subprocess.Popen(
            [sys.executable, *command, *who], cwd=ROOT, stdout=subprocess.PIPE, text=True
        )
        assert flooder.stdout is not None and flooder.stdout.readline() == "flooding\n"
    out: multiprocessing.Queue = SPAWN.Queue()
    process = SPAWN.Process(target=analytic, args=(endpoint, study, directory, config, tls, out))
    process.start()
    figures = out.get()
    process.join()
    put = 0
    if flooder is not None:
        flooder.terminate()
        put = int(flooder.communicate(timeout=30)[0].split()[-1])
    return (*figures, put)


@click.command()
@click.option("--pop", type=click.IntRange(min=4), default=8, show_default=True)
@click.option("--generations", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--mib", type=click.IntRange(min=1), default=64, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--tls", is_flag=True, help="the secure profile; the flooder is a worker")
@click.option("--keep", type=click.Choice(["front", "all"]), default="front", show_default=True)
def main(
    pop: int, generations: int, workers: int, mib: int, seed: int, tls: bool, keep: str
) -> None:
    config = RunConfig(pop=pop, generations=generations, seed=seed, keep=keep)
    endpoint = loopback_endpoint()
    with tempfile.TemporaryDirectory() as scratch:
        credentials = None
        broker_command = [sys.executable, "-m", "gainfarm.broker", "start", "--listen"]
        worker_options: list[str] = []
        if tls:
            credentials = Path(scratch) / "credentials"
            cobots = [f"cobot-{n}" for n in range(workers)]
            write_dev_credentials(credentials, analytics=("alice",), workers=[*cobots, "flooder"])
            endpoint = endpoint.replace("tcp/", "tls/")
            broker_command += [endpoint, "--tls", str(credentials)]
            worker_options = ["--tls", str(credentials)]
        else:
            broker_command += [endpoint]
        broker = subprocess.Popen([*broker_command, "--log-level", "warning"])
        time.sleep(3.0)  # the broker's router listens; each FarmClient waits for its answer
        names = [f"cobot-{n}" for n in range(workers)]
        farm = [spawn_worker(endpoint, name, "warning", *worker_options) for name in names]
        try:
            rows, fronts, peaks = [], [], []
            cases = {
                "calm": (None, False),
                f"{mib} MiB junk": (mib, False),
                f"{mib} MiB junk and forgeries": (mib, True),
            }
            for number, (case, (flood, forge)) in enumerate(cases.items()):
                study = ("alice." if tls else "") + f"case-{number}"
                directory = Path(scratch) / study
                rss, wall, counts, held, waits, front, put = measure(
                    endpoint, study, directory, config, credentials, flood, forge
                )
                fronts.append(front)
                peaks.append(rss)
                rows.append(
                    [
                        case,
                        f"{rss:.0f}",
                        f"{wall:.1f}",
                        str(put),
                        "/".join(map(str, counts)),
                        f"{held / MIB:.1f}",
                        str(waits),
                    ]
                )
        finally:
            stop_workers(farm)
            broker.terminate()
            broker.wait(30)
    profile = "secure" if tls else "plain"
    print(
        f"{profile} profile, --keep {keep}; pop {pop}, {generations} generations, {workers} workers"
    )
    print_table(
        [
            "run",
            "peak RSS MiB",
            "wall s",
            "samples put",
            "ignored/not waited/not taken/not held",
            "peak held MiB",
            "waits",
        ],
        "lrrrrrr",
        rows,
    )
    for case, peak in list(zip(cases, peaks, strict=True))[1:]:
        print(f"peak RSS, {case} / calm: {peak / peaks[0]:.2f}x")
    same = all(front == fronts[0] for front in fronts)
    print(f"same front: {same}")
    if not same:
        sys.exit(1)


if __name__ == "__main__":
    main()
