"""How the farm's throughput grows with its workers: the plumbing (stand-in workers, a client
that keeps 2N jobs in flight), then real tuning code on simulated cobots.

    python bench/scale.py [--quick] [--json] [--workers 16,64,256,1024] [--job-seconds 1]
                          [--real-workers 64,256] [--rounds 10] [--reps 1]

Plumbing (printed as such): the figures of the broker and the client alone. They are not what a
tuning run fills: the workers are NoopWorker threads (no worker code, no scoring, no log store)
and the client keeps 2 N jobs in flight, where a generational run keeps at most its population.
The broker runs as its own process (`python -m broker start`), so its CPU and its bytes are its
own. The simulated workers are threads over shared sessions in load processes (at most
WORKERS_PER_LOAD each), with their own names and liveliness tokens: each leases a job, holds it
for --job-seconds and hands in a real pre-made result, the Result and MCAP log of one episode
simulated at start-up (every job names that episode's spec, so the log is each job's own). The
real FarmClient runs in this process, keeps 2 N jobs in flight and takes in every evaluation.

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

Real runs (printed as such): a real TuningRun in this process, through a real FarmClient and the
real broker, on N CobotWorkers (the real worker code: leases in batches, hand-ins, logs kept and
served) whose physics is a sleep of --job-seconds per 5 s episode (bench/surrogate.py, the farm
of bench/campaign.py --simulated). Two figures, each the workers' time in episodes over N x the
time measured, the evaluations per second, and this process's CPU per evaluation (the run, its
client, its records and checkpoints: the analytic process):

- an --async run (population 30) for each N of --real-workers, in its steady state: from the
  end of its first generation and two jobs per worker, over --rounds jobs per worker;
- the population-size experiment (5 sizes x --reps runs, all at once, each to convergence; two
  generations with --quick) on the largest N, measured whole.

The farm is trusted, as a local farm is (these cobots are this script's own): no referee reruns
episodes. At --job-seconds J, N workers ask N / J evaluations a second of one analytic process.

Everything listens on loopback, on a port the kernel picked as free; nothing touches a farm on 7447.
"""

import contextlib
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass
from multiprocessing.connection import Connection
from pathlib import Path

import click
from campaign import cpu_seconds, simulated_campaign, simulated_farm
from common import (
    SPAWN,
    NoopWorker,
    broker_process,
    episode_specs,
    loopback_endpoint,
    percentile_ms,
)
from surrogate import EPISODE_SECONDS, read_surrogate_log

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import RunProgress, TuningRun
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.transport import open_session
from gainfarm.schemas import TrajectorySpec
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.wire import WireScores
from gainfarm.worker.job import simulate

PLUMBING = "plumbing"
PLUMBING_WHAT = (
    "NoopWorker threads over shared sessions (no worker code, no scoring, no log store), a "
    "FarmClient keeping 2N jobs in flight, no tuning loop"
)
REAL = "real run"
REAL_WHAT = (
    "a real TuningRun (--async, population 30; and the population-size experiment, its runs at "
    "once) on CobotWorkers, the real worker code, whose physics is a sleep (bench/surrogate.py)"
)
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
                for result in client.results(timeout=0.2):
                    yielded.append(time.monotonic())
                    if result.log is not None:  # --send-logs: minutes of logs fill a disk
                        result.log.unlink()
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
    """M results handed in while the client does not read, then yielded as fast as it can
    (with `send_logs`, each log fetched from its worker, still serving)."""
    endpoint = loopback_endpoint()
    with (
        broker_process(endpoint, results),
        FarmClient([endpoint], "scale-ingest", out / "ingest", keep_logs=send_logs) as client,
    ):
        client.submit({f"j{index}": episode.spec for index in range(results)})
        load = Load(endpoint, client.study, fast_workers, episode, 0.0)
        running = True
        try:
            give_up = time.monotonic() + 60 + results / 20
            while time.monotonic() < give_up:
                studies = query_status(client.session, timeout=5.0).studies
                if sum(study.done for study in studies if study.name == client.study) >= results:
                    break
                time.sleep(0.2)
            else:
                raise RuntimeError("the fast workers did not finish the ingest jobs in time")
            if not send_logs:  # with logs, its workers serve the logs the client fetches
                load.finish()
                running = False
            cpu = resource.getrusage(resource.RUSAGE_SELF)
            started = time.perf_counter()
            taken = 0
            for result in client.results():
                taken += 1
                if result.log is not None:
                    result.log.unlink()
            elapsed = time.perf_counter() - started
            after = resource.getrusage(resource.RUSAGE_SELF)
        finally:
            if running:
                load.finish()
    if taken != results:
        raise RuntimeError(f"the client yielded {taken} of {results} results")
    spent = (after.ru_utime - cpu.ru_utime) + (after.ru_stime - cpu.ru_stime)
    return Ingest(results, results / elapsed, 1e6 * spent / results)


# --- through a real tuning run -----------------------------------------------------------------


@dataclass
class RealRun:
    """What real tuning code kept busy: one --async run, or an experiment's runs at once."""

    kind: str
    workers: int
    utilisation: float  # the workers' time in episodes over workers x the time measured
    evaluations_per_s: float
    analytic_cpu_ms: float  # this process's CPU (the run, its client) per evaluation


def async_run(workers: int, job_seconds: float, rounds: int, out: Path) -> RealRun:
    """One `--async` TuningRun (population 30) on `workers` simulated cobots, measured in its
    steady state: from the evaluation after its first generation and two jobs per worker, over
    `rounds` x `workers` evaluations, its budget two jobs per worker beyond, so that the window
    never sees the run wind down."""
    pop = 30
    begin = pop + 2 * workers
    end = begin + rounds * workers
    config = RunConfig(
        pop=pop,
        trajectories=(TrajectorySpec(duration=EPISODE_SECONDS),),
        asynchronous=True,
        evaluations=end + 2 * workers,
        keep="front",
    )
    busy = SPAWN.Value("d", 0.0)
    marks: dict[str, tuple[float, float, float, int]] = {}  # time, busy s, CPU s, evaluations

    def mark(progress: RunProgress) -> None:
        for name, at in (("begin", begin), ("end", end)):
            if name not in marks and progress.evaluations >= at:
                now = (time.monotonic(), busy.value, cpu_seconds(os.getpid()))
                marks[name] = (*now, progress.evaluations)

    with (
        simulated_farm(workers, job_seconds, busy) as farm,
        FarmClient(
            [farm.endpoint],
            f"async-{workers}",
            out / f"async-{workers}",
            keep_logs=False,
            read_log=read_surrogate_log,
            trusted=True,  # this script's own cobots, as a local farm's; see campaign.py
        ) as client,
        TuningRun.create(out / f"async-{workers}" / "run", config) as run,
    ):
        run.run(client, mark)
    (t0, busy0, cpu0, evals0), (t1, busy1, cpu1, evals1) = marks["begin"], marks["end"]
    return RealRun(
        kind="async run",
        workers=workers,
        utilisation=(busy1 - busy0) / (workers * (t1 - t0)),
        evaluations_per_s=(evals1 - evals0) / (t1 - t0),
        analytic_cpu_ms=1000 * (cpu1 - cpu0) / (evals1 - evals0),
    )


def experiment(
    workers: int, job_seconds: float, reps: int, generations: int | None, out: Path
) -> RealRun:
    """The population-size experiment (its 5 sizes x `reps` runs at once, each to convergence
    or to `generations`) on `workers` simulated cobots: bench/campaign.py --simulated's,
    measured whole."""
    with contextlib.redirect_stdout(sys.stderr):  # its progress lines; stdout is the figures'
        figures = simulated_campaign(
            out / f"experiment-{workers}",
            workers,
            job_seconds,
            reps,
            "realistic",
            ["popsize"],
            generations,
        )
    runs = f"{5 * reps} runs, " + (f"{generations} generations" if generations else "converged")
    return RealRun(
        kind=f"experiment popsize ({runs})",
        workers=workers,
        utilisation=figures.utilisation,
        evaluations_per_s=figures.jobs / figures.wall,
        analytic_cpu_ms=1000 * figures.cpu["analytic"] / figures.jobs,
    )


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
@click.option("--quick", is_flag=True, help="a smoke run: small N, short windows")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object, nothing else")
@click.option(
    "--workers",
    "worker_counts",
    help="plumbing: simulated workers N, comma-separated  "
    "[default: 16,64,256,1024; --quick: 16,64]",
)
@click.option(
    "--real-workers",
    "real_counts",
    help="real runs: simulated cobots N, comma-separated; the experiment runs on the largest  "
    "[default: 64,256; --quick: 16]",
)
@click.option(
    "--rounds",
    type=click.IntRange(min=1),
    help="the --async run's steady-state window, in jobs per cobot  [default: 10; --quick: 3]",
)
@click.option(
    "--reps",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="the experiment's repetitions of its 5 population sizes",
)
@click.option(
    "--job-seconds",
    type=click.FloatRange(min=0, min_open=True),
    default=1.0,
    show_default=True,
    help="how long a simulated worker holds each job (a 5 s episode)",
)
@click.option(
    "--duration",
    type=click.FloatRange(min=0.5),
    default=5.0,
    show_default=True,
    help="plumbing: the pre-made episode's duration, s (its log is what every result carries)",
)
@click.option(
    "--window",
    type=click.FloatRange(min=0, min_open=True),
    help="plumbing: s  [default: 20; --quick: 5]",
)
@click.option(
    "--send-logs",
    is_flag=True,
    help="plumbing: every result's log is fetched from its worker once it is confirmed (as "
    "`--keep all` runs do); by default the workers keep them",
)
@click.option(
    "--ingest",
    "ingest_results",
    type=click.IntRange(min=1),
    help="plumbing: results M for analytic_ingest_per_s  [default: 3000; --quick: 500]",
)
def main(
    quick: bool,
    as_json: bool,
    worker_counts: str | None,
    real_counts: str | None,
    rounds: int | None,
    reps: int,
    job_seconds: float,
    duration: float,
    window: float | None,
    ingest_results: int | None,
    send_logs: bool,
) -> None:
    sizes = _counts("--workers", worker_counts, [16, 64] if quick else [16, 64, 256, 1024])
    real_sizes = _counts("--real-workers", real_counts, [16] if quick else [64, 256])
    rounds = rounds or (3 if quick else 10)
    generations = 2 if quick else None  # a smoke run's experiment: 2 generations, not converged
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
                f"{PLUMBING}, N={workers}: utilisation {100 * run.utilisation:.1f} %, "
                f"{run.results_per_s:.0f} results/s, {run.leases_per_s:.0f} leases/s, "
                f"{run.broker_bytes_per_job / 1e3:.1f} kB/job through the broker, "
                f"lease p99 {run.lease_p99_ms:.1f} ms"
            )
            runs.append(asdict(run))
            shutil.rmtree(out / f"n{workers}", ignore_errors=True)
        taken = ingest(ingest_results, episode, out, send_logs)
        say(
            f"{PLUMBING}, analytic ingest (results pre-delivered, no tuning loop): "
            f"{taken.per_s:.0f} results/s over {taken.results} results, "
            f"{taken.cpu_us_per_result:.0f} µs CPU each"
        )
        real: list[RealRun] = []

        def measured(figure: RealRun) -> None:
            real.append(figure)
            say(
                f"{REAL}, {figure.kind}, N={figure.workers}: the workers in episodes "
                f"{100 * figure.utilisation:.1f} % of the time, "
                f"{figure.evaluations_per_s:.1f} evaluations/s, analytic CPU "
                f"{figure.analytic_cpu_ms:.2f} ms per evaluation"
            )

        for workers in real_sizes:
            measured(async_run(workers, job_seconds, rounds, out))
        measured(experiment(max(real_sizes), job_seconds, reps, generations, out))
        busy = [f.workers for f in real[:-1] if f.utilisation >= 0.9]
        tried = ", ".join(map(str, real_sizes))
        say(
            f"{REAL}: the most workers one --async run kept >= 90 % busy at {job_seconds:g} s "
            f"jobs: {max(busy) if busy else 'none'} (of {tried} tried)"
        )
    finally:
        shutil.rmtree(out, ignore_errors=True)
    print(
        json.dumps(
            {
                "plumbing": {
                    "what": PLUMBING_WHAT,
                    "runs": runs,
                    "analytic_ingest_per_s": taken.per_s,
                    "analytic_cpu_us_per_result": taken.cpu_us_per_result,
                    "ingest_results": taken.results,
                    "window_s": window,
                    "episode_log_bytes": episode.size,
                    "logs": "fetched with each result" if send_logs else "kept by the workers",
                },
                "real": {"what": REAL_WHAT, "runs": [asdict(figure) for figure in real]},
                "job_seconds": job_seconds,
            },
            indent=None if as_json else 2,
        )
    )


def _counts(option: str, text: str | None, default: list[int]) -> list[int]:
    try:
        return counts(text) if text else default
    except click.BadParameter as error:
        raise click.UsageError(f"{option}: {error.message}") from None


if __name__ == "__main__":
    main()
