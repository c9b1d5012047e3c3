"""How the farm's throughput grows with its workers: simulated workers over the real broker and
the real analytic client.

    python bench/scale.py [--quick] [--json] [--workers 16,64,256,1024] [--job-seconds 1]

The broker runs as its own process (`python -m broker start`), so its CPU and its bytes are its
own. The simulated workers are threads over shared sessions in load processes (at most
WORKERS_PER_LOAD each), with their own names and liveliness tokens: each leases a job, holds it
for --job-seconds and hands in a real pre-made result, the Result and MCAP log of one episode
simulated at start-up (every job names that episode's spec, so the log is each job's own). The
real FarmClient runs in this process, keeps 2 N jobs in flight and takes in every evaluation as
a tuning run does.

For each N, after a warm-up of two jobs' time, over a window:

- utilisation: the workers' time holding jobs within the window, over N x window;
- results_per_s: evaluations the client yielded within the window, over the window;
- leases_per_s: leases granted within the window, over the window;
- broker_bytes_per_job: bytes sent and received on the broker's port within the window (Zenoh's
  framing included, `ss`), over the evaluations yielded in it;
- lease_p99_ms: the 99th percentile of the time to a lease, of leases asked for within the window.

analytic_ingest_per_s: M jobs are run by fast workers (no hold) while the client does not read;
once the broker has taken all M, the client yields them, as fast as it can, and the figure is M
over the time it takes. analytic_cpu_us_per_result is this process's CPU time over M.

Everything listens on loopback, on a port the kernel picked as free; nothing touches a farm on 7447.
"""

import contextlib
import json
import re
import resource
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass
from multiprocessing.connection import Connection
from pathlib import Path

import click
from common import SPAWN, NoopWorker, episode_specs, loopback_endpoint, percentile_ms

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.transport import open_session
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.wire import WireScores
from gainfarm.worker.job import simulate

WORKERS_PER_LOAD = 256  # simulated workers per load process
SESSIONS_PER_LOAD = 8  # sessions a load process's workers share
STARTUP_SECONDS = 20.0  # for the broker and the workers to come up


# --- the episode every job names ---------------------------------------------------------------


@dataclass
class PremadeEpisode:
    spec: EpisodeSpec
    path: Path
    size: int
    scores: WireScores


def premade_episode(duration: float, out: Path) -> PremadeEpisode:
    spec = episode_specs(1, duration)[0]
    outcome = simulate(spec)
    assert outcome.scores is not None, outcome.reason
    path = out / "premade.mcap"
    path.write_bytes(outcome.content)
    return PremadeEpisode(
        spec, path, len(outcome.content), WireScores(**outcome.scores.model_dump())
    )


# --- the load ----------------------------------------------------------------------------------


def sim_load(
    endpoint: str,
    study: str,
    names: list[str],
    log_path: str,
    scores: dict,
    job_seconds: float,
    stop: threading.Event,
    parent: Connection,
) -> None:
    """Serve `names` as simulated workers until `stop`; send back their leases and job runs."""
    log = Path(log_path).read_bytes()
    shared = [open_session("client", connect=[endpoint]) for _ in range(SESSIONS_PER_LOAD)]
    claimed = WireScores(**scores)
    farm = [
        NoopWorker(shared[i % len(shared)], name, study, log, claimed)
        for i, name in enumerate(names)
    ]
    hold = (lambda: time.sleep(job_seconds)) if job_seconds > 0 else None

    def serve(worker: NoopWorker) -> None:
        try:
            worker.serve(stop, hold)
        except RuntimeError:  # the broker went first: the bench is over
            if not stop.is_set():
                raise

    threads = [threading.Thread(target=serve, args=(worker,)) for worker in farm]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    parent.send(
        {
            "runs": [(start, end) for worker in farm for _, start, end in worker.runs],
            "leases": [lease for worker in farm for lease in worker.leases],
            "completed": sum(worker.completed for worker in farm),
        }
    )
    for worker in farm:
        worker.close()
    for session in shared:
        session.close()


class Load:
    """Load processes serving `workers` simulated workers on study `study`."""

    def __init__(
        self, endpoint: str, study: str, workers: int, episode: PremadeEpisode, job_seconds: float
    ):
        self.stop = SPAWN.Event()
        self.processes = []
        self.pipes = []
        names = [f"sim-{index}" for index in range(workers)]
        for start in range(0, workers, WORKERS_PER_LOAD):
            receiver, sender = SPAWN.Pipe(duplex=False)
            process = SPAWN.Process(
                target=sim_load,
                args=(
                    endpoint,
                    study,
                    names[start : start + WORKERS_PER_LOAD],
                    str(episode.path),
                    episode.scores.model_dump(),
                    job_seconds,
                    self.stop,
                    sender,
                ),
            )
            process.start()
            self.processes.append(process)
            self.pipes.append(receiver)

    def finish(self) -> dict:
        """Stop the workers; their runs, leases and completed jobs, all processes together."""
        self.stop.set()
        merged: dict = {"runs": [], "leases": [], "completed": 0}
        for pipe, process in zip(self.pipes, self.processes, strict=True):
            report = pipe.recv()
            process.join()
            merged["runs"] += report["runs"]
            merged["leases"] += report["leases"]
            merged["completed"] += report["completed"]
        return merged


# --- the broker --------------------------------------------------------------------------------


@contextlib.contextmanager
def broker_process(endpoint: str, queued: int):
    """The real broker, alone in its process."""
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "gainfarm.broker",
            "start",
            "--listen",
            endpoint,
            "--max-queued",
            str(max(queued, 100_000)),
            "--max-queued-per-study",
            str(max(queued, 20_000)),
            "--log-level",
            "warning",
        ],
        stdin=subprocess.DEVNULL,
    )
    try:
        port = int(endpoint.rsplit(":", 1)[1])
        give_up = time.monotonic() + STARTUP_SECONDS
        while True:  # until it listens
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
                break
            except OSError:
                if time.monotonic() > give_up or process.poll() is not None:
                    raise RuntimeError(f"the broker did not listen on {endpoint}") from None
                time.sleep(0.1)
        yield process
    finally:
        process.terminate()
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def port_bytes(port: int) -> int:
    """Bytes sent and received so far on the established connections of local port `port`."""
    listing = subprocess.run(
        ["ss", "-tinH", "state", "established", f"( sport = :{port} )"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return sum(int(count) for count in re.findall(r"bytes_(?:sent|received):(\d+)", listing))


def wait_for_workers(client: FarmClient, workers: int) -> None:
    give_up = time.monotonic() + STARTUP_SECONDS + workers / 20
    while time.monotonic() < give_up:
        with contextlib.suppress(BrokerUnavailable):
            if query_status(client.session, timeout=2.0).worker_count >= workers:
                return
        time.sleep(0.2)
    raise RuntimeError(f"{workers} simulated workers did not all join the broker in time")


# --- one N -------------------------------------------------------------------------------------


@dataclass
class Scale:
    workers: int
    utilisation: float
    results_per_s: float
    leases_per_s: float
    broker_bytes_per_job: float
    lease_p99_ms: float


def scale(
    workers: int,
    job_seconds: float,
    window: float,
    episode: PremadeEpisode,
    out: Path,
    send_logs: bool,
) -> Scale:
    endpoint = loopback_endpoint()
    port = int(endpoint.rsplit(":", 1)[1])
    in_flight = 2 * workers
    with (
        broker_process(endpoint, in_flight * 2),
        FarmClient(
            [endpoint], f"scale-{workers}", out / f"n{workers}", keep_logs=send_logs
        ) as client,
    ):
        serial = iter(range(10**9))

        def top_up() -> None:
            missing = in_flight - client.pending
            if missing > 0:
                client.submit({f"j{next(serial)}": episode.spec for _ in range(missing)})

        top_up()
        load = Load(endpoint, client.study, workers, episode, job_seconds)
        try:
            wait_for_workers(client, workers)
            start = time.monotonic() + 2 * job_seconds
            end = start + window
            yielded: list[float] = []
            bytes_at: dict[str, int] = {}
            while time.monotonic() < end:
                for evaluation in client.results(timeout=0.2):
                    yielded.append(time.monotonic())
                    if evaluation.log is not None:  # --send-logs: minutes of logs fill a disk
                        evaluation.log.unlink()
                    if len(yielded) % 16 == 0:
                        top_up()
                    if "start" not in bytes_at and time.monotonic() >= start:
                        bytes_at["start"] = port_bytes(port)
                    if time.monotonic() >= end:
                        break
                top_up()
                if "start" not in bytes_at and time.monotonic() >= start:
                    bytes_at["start"] = port_bytes(port)
            bytes_at["end"] = port_bytes(port)
        finally:
            report = load.finish()
    done = sum(1 for moment in yielded if start <= moment < end)
    leased = [latency for asked, latency in report["leases"] if start <= asked < end]
    busy = sum(max(0.0, min(finish, end) - max(begin, start)) for begin, finish in report["runs"])
    if job_seconds <= 0:
        busy = float("nan")
    return Scale(
        workers=workers,
        utilisation=busy / (workers * window),
        results_per_s=done / window,
        leases_per_s=len(leased) / window,
        broker_bytes_per_job=(bytes_at["end"] - bytes_at["start"]) / max(done, 1),
        lease_p99_ms=percentile_ms(leased, 99) if leased else float("nan"),
    )


# --- ingest ------------------------------------------------------------------------------------


@dataclass
class Ingest:
    results: int
    per_s: float
    cpu_us_per_result: float


def ingest(
    results: int, episode: PremadeEpisode, out: Path, send_logs: bool, fast_workers: int = 8
) -> Ingest:
    """M results handed in while the client does not read, then yielded as fast as it can."""
    endpoint = loopback_endpoint()
    with (
        broker_process(endpoint, results),
        FarmClient([endpoint], "scale-ingest", out / "ingest", keep_logs=send_logs) as client,
    ):
        client.submit({f"j{index}": episode.spec for index in range(results)})
        load = Load(endpoint, client.study, fast_workers, episode, 0.0)
        try:
            give_up = time.monotonic() + 60 + results / 20
            while time.monotonic() < give_up:
                studies = query_status(client.session, timeout=5.0).studies
                if sum(study.done for study in studies if study.name == client.study) >= results:
                    break
                time.sleep(0.2)
            else:
                raise RuntimeError("the fast workers did not finish the ingest jobs in time")
        finally:
            load.finish()
        cpu = resource.getrusage(resource.RUSAGE_SELF)
        started = time.perf_counter()
        taken = 0
        for evaluation in client.results():
            taken += 1
            if evaluation.log is not None:
                evaluation.log.unlink()
        elapsed = time.perf_counter() - started
        after = resource.getrusage(resource.RUSAGE_SELF)
    if taken != results:
        raise RuntimeError(f"the client yielded {taken} of {results} results")
    spent = (after.ru_utime - cpu.ru_utime) + (after.ru_stime - cpu.ru_stime)
    return Ingest(results, results / elapsed, 1e6 * spent / results)


# --- the command -------------------------------------------------------------------------------


def counts(text: str) -> list[int]:
    try:
        values = [int(part) for part in text.split(",")]
    except ValueError:
        raise click.BadParameter("comma-separated whole numbers, e.g. 16,64") from None
    if not values or min(values) < 1:
        raise click.BadParameter("each at least 1")
    return values


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--quick", is_flag=True, help="a smoke run: N = 16 and 64, short windows")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object, nothing else")
@click.option(
    "--workers",
    "worker_counts",
    help="simulated workers N, comma-separated  [default: 16,64,256,1024; --quick: 16,64]",
)
@click.option(
    "--job-seconds",
    type=click.FloatRange(min=0, min_open=True),
    default=1.0,
    show_default=True,
    help="how long a simulated worker holds each job",
)
@click.option(
    "--duration",
    type=click.FloatRange(min=0.5),
    default=5.0,
    show_default=True,
    help="the pre-made episode's duration, s (its log is what every result carries)",
)
@click.option(
    "--window", type=click.FloatRange(min=0, min_open=True), help="s  [default: 20; --quick: 5]"
)
@click.option(
    "--send-logs",
    is_flag=True,
    help="every result brings its log (as `--keep all` runs do); by default the workers keep them",
)
@click.option(
    "--ingest",
    "ingest_results",
    type=click.IntRange(min=1),
    help="results M for analytic_ingest_per_s  [default: 3000; --quick: 500]",
)
def main(
    quick: bool,
    as_json: bool,
    worker_counts: str | None,
    job_seconds: float,
    duration: float,
    window: float | None,
    ingest_results: int | None,
    send_logs: bool,
) -> None:
    try:
        sizes = (
            counts(worker_counts) if worker_counts else ([16, 64] if quick else [16, 64, 256, 1024])
        )
    except click.BadParameter as error:
        raise click.UsageError(f"--workers: {error.message}") from None
    window = window or (5.0 if quick else 20.0)
    ingest_results = ingest_results or (500 if quick else 3000)
    say = (lambda *_: None) if as_json else (lambda text: print(text, file=sys.stderr, flush=True))
    out = Path(tempfile.mkdtemp(prefix="gainfarm-scale-"))
    try:
        episode = premade_episode(duration, out)
        say(f"pre-made episode: {duration:g} s, {episode.size / 1e6:.2f} MB log")
        runs = []
        for workers in sizes:
            run = scale(workers, job_seconds, window, episode, out, send_logs)
            say(
                f"N={workers}: utilisation {100 * run.utilisation:.1f} %, "
                f"{run.results_per_s:.0f} results/s, {run.leases_per_s:.0f} leases/s, "
                f"{run.broker_bytes_per_job / 1e3:.1f} kB/job through the broker, "
                f"lease p99 {run.lease_p99_ms:.1f} ms"
            )
            runs.append(asdict(run))
            shutil.rmtree(out / f"n{workers}", ignore_errors=True)
        taken = ingest(ingest_results, episode, out, send_logs)
        say(
            f"analytic ingest: {taken.per_s:.0f} results/s over {taken.results} results, "
            f"{taken.cpu_us_per_result:.0f} µs CPU each"
        )
    finally:
        shutil.rmtree(out, ignore_errors=True)
    print(
        json.dumps(
            {
                "runs": runs,
                "analytic_ingest_per_s": taken.per_s,
                "analytic_cpu_us_per_result": taken.cpu_us_per_result,
                "ingest_results": taken.results,
                "job_seconds": job_seconds,
                "window_s": window,
                "episode_log_bytes": episode.size,
                "logs": "sent with each result" if send_logs else "kept by the workers",
            },
            indent=None if as_json else 2,
        )
    )


if __name__ == "__main__":
    main()
