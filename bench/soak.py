"""Soak the farm: a long stream of short jobs while workers come and go, and the memory of every
process over time.

    python bench/soak.py [--minutes 60 | --quick] [--workers-min 1] [--workers-max 4] [--seed 0]
        [--sample-seconds 5] [--out soak.csv] [--events events.csv] [--broker-log broker.log]

The broker runs as a subprocess (`python -m broker start`), so its memory is its own, and so do
the workers (`python -m worker start`). One resident worker serves the whole run, so that a
worker-side leak shows as a slope; the others churn: every `--churn-seconds` a seeded draw starts
one, stops one with SIGTERM (it finishes its job first) or SIGKILLs one the broker sees busy,
keeping between `--workers-min` and `--workers-max` (`--no-churn`: a fixed pool, to tell leaks
from churn). A FarmClient in this process keeps `--pending` short jobs in flight (0.2-0.5 s
episodes, a few ms of simulation each) and submits more as results come in. The workers keep the
logs, and every `--fetch-every`th episode's log is fetched a churn period after its result, when
its worker may be gone (then it is simulated again elsewhere, to the same bytes); a log that
cannot be had counts as a job lost. At the end it drains (no more submissions, every pending job
waited for, every fetch done), then stops the workers and the broker.

Every `--sample-seconds` it reads VmRSS, RssAnon and RssShmem from /proc/PID/status of the broker,
this process and each worker; `--out` gets them as CSV (seconds, role, name, pid, rss_mib,
anon_mib, shmem_mib; plus "workers max" and "workers mean" rows per sample), `--events` the
workers' starts, SIGTERMs and SIGKILLs. A ledger keeps what came back for each job. At the end it
prints its figures (bench/soak_summary.py, which says how each is measured, and which also
reads an `--out` CSV on its own): jobs submitted, completed, lost, duplicated and retried; worker
starts, stops and kills; memory at start, after the warm-up and at the end with its slope after
the warm-up for the broker, the client and the resident worker; throughput. Exit status 1 if a
job was lost or duplicated, or a worker died unbidden or hung.

Everything listens on loopback, on a port the kernel picked as free; nothing touches a farm on 7447.
"""

import csv
import io
import logging
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path

import click
from common import loopback_endpoint, scaled_gains
from soak_summary import (
    Sample,
    SoakLedger,
    WorkerTally,
    broker_line,
    job_lines,
    memory_lines,
    samples_csv,
)

from gainfarm.analytic.evaluators import replication
from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Wanted
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import STOP_SECONDS, spawn_worker
from gainfarm.broker.status import BrokerUnavailable
from gainfarm.edges.files import write_atomically
from gainfarm.edges.transport import open_session, token_held
from gainfarm.schemas import EpisodeSpec, TrajectorySpec, keys
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.wire import BadMessage, BrokerStatus

STUDY = "soak"
DURATIONS = (0.2, 0.3, 0.4, 0.5)  # s of simulated motion per job (fourier: feasible at any)
RANDOM_SEEDS = (0, 1)
# Action weights of one churn step; kills are the rarer event, as in a real farm.
CHURN_WEIGHTS = {"start": 0.4, "stop": 0.4, "kill": 0.2}
BROKER_START_SECONDS = 30.0
PROGRESS_SECONDS = 60.0
LOG_MEMORY_MIB = 16  # each worker's kept logs: full within a minute of short jobs
CSV_EVERY_SAMPLES = 12  # rewrite --out this often, so a crashed soak still leaves its samples


# --- memory ------------------------------------------------------------------------------------


STATUS_FIELDS = ("VmRSS", "RssAnon", "RssShmem")


def resident_mib(pid: int) -> tuple[float, float, float] | None:
    """VmRSS of a live process, and its RssAnon and RssShmem parts, in MiB; None once it has
    gone (a zombie has no VmRSS). The parts tell a heap that grows from shared memory mapped in
    (Zenoh's transport puts large payloads of local peers in shared-memory segments)."""
    found: dict[str, float] = {}
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                key, _, value = line.partition(":")
                if key in STATUS_FIELDS:
                    found[key] = int(value.split()[0]) / 1024
    except (FileNotFoundError, ProcessLookupError):
        return None
    if len(found) < len(STATUS_FIELDS):
        return None
    return found["VmRSS"], found["RssAnon"], found["RssShmem"]


class Sampler:
    """Samples the RSS of registered processes on its own thread, so a stalled client loop (a
    hang is one of the things a soak looks for) does not stall the record of memory."""

    def __init__(self, period: float, out: Path | None, started: float):
        self.period = period
        self.out = out
        self.started = started
        self.samples: list[Sample] = []
        self._processes: dict[int, tuple[str, str]] = {}  # pid → (role, name)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="soak-sampler", daemon=True)

    def watch(self, pid: int, role: str, name: str) -> None:
        with self._lock:
            self._processes[pid] = (role, name)

    def forget(self, pid: int) -> None:
        with self._lock:
            self._processes.pop(pid, None)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sample()
        self.write()

    def sample(self) -> None:
        now = time.monotonic() - self.started
        with self._lock:
            processes = list(self._processes.items())
        workers = []
        for pid, (role, name) in processes:
            resident = resident_mib(pid)
            if resident is None:
                continue
            self.samples.append(Sample(now, role, name, pid, *resident))
            if role == "worker":
                workers.append(resident)
        if workers:
            columns = list(zip(*workers, strict=True))
            self.samples.append(Sample(now, "workers", "max", 0, *map(max, columns)))
            self.samples.append(Sample(now, "workers", "mean", 0, *map(statistics.fmean, columns)))

    def write(self) -> None:
        if self.out is not None:
            write_atomically(self.out, samples_csv(list(self.samples)))

    def _run(self) -> None:
        count = 0
        while not self._stop.wait(self.period):
            self.sample()
            count += 1
            if count % CSV_EVERY_SAMPLES == 0:
                self.write()


# --- processes ---------------------------------------------------------------------------------


def start_broker(endpoint: str, lease_seconds: float, log: Path | None) -> subprocess.Popen:
    stderr = log.open("ab") if log is not None else None
    command = [sys.executable, "-m", "gainfarm.broker", "start", "--listen", endpoint]
    command += ["--lease-seconds", str(lease_seconds)]
    command += ["--log-level", "info" if log is not None else "warning"]
    broker = subprocess.Popen(command, stdin=subprocess.DEVNULL, stderr=stderr)
    if stderr is not None:
        stderr.close()  # the child holds its own copy
    # Wait for the broker's liveliness token, which it declares last: a FarmClient opened
    # before it would see it appear, take it for a broker restart and resubmit everything.
    give_up = time.monotonic() + BROKER_START_SECONDS
    while time.monotonic() < give_up:
        if broker.poll() is not None:
            raise RuntimeError(f"the broker exited with status {broker.returncode} at start")
        try:
            session = open_session("client", connect=[endpoint])
        except ConnectionError:  # not listening yet
            time.sleep(0.1)
            continue
        try:
            while time.monotonic() < give_up and broker.poll() is None:
                if token_held(session, keys.ALIVE_BROKER):
                    return broker
                time.sleep(0.05)
        finally:
            session.close()
    broker.kill()
    raise RuntimeError(f"the broker was not serving on {endpoint} after {BROKER_START_SECONDS:g} s")


@dataclass
class WorkerPool:
    """Worker subprocesses: one resident, the rest started, stopped and killed by `churn`."""

    endpoint: str
    sampler: Sampler
    rng: random.Random
    low: int
    high: int
    started: float
    live: dict[str, subprocess.Popen] = field(default_factory=dict)
    stopping: dict[str, tuple[subprocess.Popen, float]] = field(default_factory=dict)
    resident: str = ""
    serial: int = 0
    tally: WorkerTally = field(default_factory=WorkerTally)
    events: list[tuple[float, str, str, str]] = field(default_factory=list)

    def note(self, event: str, name: str) -> None:
        """Keep what happened to whom and when, in wall-clock time too, to read beside the
        broker's log when a job goes astray."""
        seconds = time.monotonic() - self.started
        self.events.append((seconds, time.strftime("%H:%M:%S"), event, name))

    def write_events(self, path: Path) -> None:
        text = io.StringIO()
        writer = csv.writer(text, lineterminator="\n")
        writer.writerow(["seconds", "clock", "event", "worker"])
        writer.writerows((f"{seconds:.2f}", *rest) for seconds, *rest in self.events)
        write_atomically(path, text.getvalue().encode())

    def start(self) -> None:
        name = f"soak-{self.serial}"
        self.serial += 1
        # A small log store fills within the warm-up: past it, a growing worker is a leak.
        process = spawn_worker(self.endpoint, name, "warning", "--log-memory", str(LOG_MEMORY_MIB))
        self.live[name] = process
        self.sampler.watch(process.pid, "worker", name)
        self.tally.starts += 1
        self.resident = self.resident or name
        self.note("start", name)

    def stop(self, name: str) -> None:
        process = self.live.pop(name)
        process.terminate()
        self.stopping[name] = (process, time.monotonic())
        self.tally.stops += 1
        self.note("sigterm", name)

    def kill(self, name: str) -> None:
        process = self.live.pop(name)
        process.kill()
        process.wait()
        self.sampler.forget(process.pid)
        self.tally.kills += 1
        self.note("sigkill", name)

    def reap(self) -> None:
        """Collect stopped workers, SIGKILL those past STOP_SECONDS, notice any that died."""
        now = time.monotonic()
        for name, (process, since) in list(self.stopping.items()):
            if process.poll() is None and now - since > STOP_SECONDS:
                self.tally.hung.append(name)
                self.note("hung", name)
                process.kill()
                process.wait()
            if process.poll() is not None:
                del self.stopping[name]
                self.sampler.forget(process.pid)
                self.tally.stop_codes[process.returncode] += 1
        for name, process in list(self.live.items()):
            if process.poll() is not None:
                self.tally.died.append(f"{name} (status {process.returncode})")
                self.note("died", name)
                del self.live[name]
                self.sampler.forget(process.pid)
                if name == self.resident:
                    self.resident = ""
        while len(self.live) < self.low:
            self.start()

    def churn(self, busy: set[str]) -> None:
        """One seeded step: start a worker, SIGTERM one, or SIGKILL one that is mid-job."""
        self.reap()
        action = self.rng.choices(list(CHURN_WEIGHTS), weights=list(CHURN_WEIGHTS.values()))[0]
        others = sorted(name for name in self.live if name != self.resident)
        if action == "kill" and not busy & set(others):
            action = "stop"  # no job to interrupt: a plain stop keeps the draw's rhythm
        if action != "start" and not others:
            action = "start"
        if action == "start" and len(self.live) >= self.high:
            action = "stop"
        if action != "start" and not others:
            return  # only the resident, and no room for another worker
        if action == "start":
            self.start()
            return
        if len(self.live) - 1 < self.low:  # the replacement first: never below the minimum
            self.start()
        if action == "kill":
            self.kill(self.rng.choice(sorted(busy & set(others))))
        else:
            self.stop(self.rng.choice(others))

    def close(self) -> None:
        for name in list(self.live):
            self.stop(name)
        give_up = time.monotonic() + STOP_SECONDS + 1
        while self.stopping and time.monotonic() < give_up:
            self.reap_stopping()
            time.sleep(0.1)
        self.reap_stopping(force=True)

    def reap_stopping(self, force: bool = False) -> None:
        for name, (process, _) in list(self.stopping.items()):
            if force and process.poll() is None:
                self.tally.hung.append(name)
                self.note("hung", name)
                process.kill()
                process.wait()
            if process.poll() is not None:
                del self.stopping[name]
                self.sampler.forget(process.pid)
                self.tally.stop_codes[process.returncode] += 1


# --- jobs --------------------------------------------------------------------------------------


def job_spec(rng: random.Random) -> EpisodeSpec:
    """A short episode. Few distinct trajectories (16), so the workers' reference cache (64
    entries) keeps hitting, as it does in a real study; gains vary freely. Fourier excitations:
    the one kind the iiwa's limits allow at a fraction of a second."""
    seed = rng.choice(RANDOM_SEEDS)
    trajectory = TrajectorySpec(kind="fourier", duration=rng.choice(DURATIONS), seed=seed)
    gains = scaled_gains(
        [rng.uniform(0.7, 1.3) for _ in DEFAULT_GAINS.kp],
        [rng.uniform(0.7, 1.3) for _ in DEFAULT_GAINS.kd],
    )
    return EpisodeSpec(gains=gains, trajectory=trajectory)


# --- the soak ----------------------------------------------------------------------------------


class ClientWarnings(logging.Handler):
    """Counts FarmClient's warnings by message (a rejoin after the broker's token appeared, a
    resubmission at the deadline, an ignored result) and echoes the first few of each: they are
    a soak's early signs of trouble, and FarmClient keeps no counter of its own for them."""

    def __init__(self, started: float):
        super().__init__(logging.WARNING)
        self.started = started
        self.counts: Counter[str] = Counter()

    def emit(self, record: logging.LogRecord) -> None:
        self.counts[str(record.msg)] += 1
        if self.counts[str(record.msg)] <= 3:
            echo(self.started, f"client warning: {record.getMessage()}")


def broker_status(farm: FarmClient) -> BrokerStatus | None:
    try:
        return farm.status()
    except (BrokerUnavailable, BadMessage):
        return None


def echo(started: float, text: str) -> None:
    click.echo(f"[{time.monotonic() - started:7.1f} s] {text}")


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--minutes", type=click.FloatRange(min=0.1), default=60.0, show_default=True)
@click.option("--quick", is_flag=True, help="a 1-minute smoke run (overrides --minutes)")
@click.option("--workers-min", type=click.IntRange(min=1), default=1, show_default=True)
@click.option("--workers-max", type=click.IntRange(min=1), default=4, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True, help="seeds jobs and churn")
@click.option("--sample-seconds", type=click.FloatRange(min=0.1), default=5.0, show_default=True)
@click.option(
    "--churn-seconds",
    type=click.FloatRange(min=0.1),
    default=5.0,
    show_default=True,
    help="time between worker starts, stops and kills",
)
@click.option(
    "--churn/--no-churn",
    default=True,
    show_default=True,
    help="workers come and go; without, a fixed --workers-min, to tell leaks from churn",
)
@click.option(
    "--pending",
    type=click.IntRange(min=1),
    default=16,
    show_default=True,
    help="jobs the client keeps in flight",
)
@click.option(
    "--warm-up-minutes",
    type=click.FloatRange(min=0),
    help="memory before this is left out of the slopes  [default: a fifth of the run, ≤ 5]",
)
@click.option(
    "--deadline",
    type=click.FloatRange(min=1),
    default=60.0,
    show_default=True,
    help="s before the client resubmits a job with no result",
)
@click.option("--attempts", type=click.IntRange(min=1), default=3, show_default=True)
@click.option(
    "--replicate-every",
    type=click.IntRange(min=0),
    default=10,
    show_default=True,
    help="validate every Nth episode: the referee runs it again in this process (0: none)",
)
@click.option(
    "--fetch-every",
    type=click.IntRange(min=0),
    default=10,
    show_default=True,
    help="the workers keep the logs, and every Nth episode's is fetched a churn period later, "
    "when its worker may be gone (simulated again elsewhere then); 0: every log comes with its "
    "result",
)
@click.option("--lease-seconds", type=click.FloatRange(min=0.1), default=60.0, show_default=True)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="CSV of memory samples: seconds, role, name, pid, rss_mib, anon_mib, shmem_mib "
    "(bench/soak_summary.py reads it)",
)
@click.option(
    "--events",
    type=click.Path(dir_okay=False, path_type=Path),
    help="CSV of worker starts, SIGTERMs, SIGKILLs: seconds, clock, event, worker",
)
@click.option(
    "--broker-log",
    type=click.Path(dir_okay=False, path_type=Path),
    help="the broker's log at info level (otherwise warnings on stderr)",
)
def main(
    minutes: float,
    quick: bool,
    workers_min: int,
    workers_max: int,
    seed: int,
    sample_seconds: float,
    churn_seconds: float,
    churn: bool,
    pending: int,
    warm_up_minutes: float | None,
    deadline: float,
    attempts: int,
    replicate_every: int,
    fetch_every: int,
    lease_seconds: float,
    out: Path | None,
    events: Path | None,
    broker_log: Path | None,
) -> None:
    if workers_max < workers_min:
        raise click.BadParameter("must be at least --workers-min", param_hint="--workers-max")
    if quick:
        minutes, sample_seconds, churn_seconds = 1.0, min(sample_seconds, 2.0), 3.0
    warm_up = 60 * (warm_up_minutes if warm_up_minutes is not None else min(minutes / 5, 5.0))
    if out is not None and not out.parent.is_dir():
        raise click.BadParameter(f"{out.parent} is not a directory", param_hint="--out")

    started = time.monotonic()
    endpoint = loopback_endpoint()
    sampler = Sampler(sample_seconds, out, started)
    ledger = SoakLedger()
    replicas = replication.Ledger()
    referee = InProcessEvaluator()
    job_rng, churn_rng = random.Random(seed), random.Random(seed + 1)
    pool = WorkerPool(endpoint, sampler, churn_rng, workers_min, workers_max, started)
    broker = start_broker(endpoint, lease_seconds, broker_log)
    sampler.watch(broker.pid, "broker", "broker")
    sampler.watch(os.getpid(), "client", "client")
    final_status: BrokerStatus | None = None
    broker_code: int | None = None
    warnings = ClientWarnings(started)
    logging.getLogger("gainfarm.analytic").addHandler(warnings)
    try:
        pool.start()  # the resident
        while len(pool.live) < workers_min:
            pool.start()
        sampler.start()
        echo(started, f"broker on {endpoint}, {len(pool.live)} workers; soaking {minutes:g} min")
        with (
            tempfile.TemporaryDirectory(prefix="soak-") as scratch,
            FarmClient(
                [endpoint],
                STUDY,
                Path(scratch),
                deadline=deadline,
                attempts=attempts,
                keep_logs=fetch_every == 0,
            ) as farm,
        ):
            to_fetch: deque[tuple[float, EpisodeResult]] = deque()  # (when, evaluation)

            def fetch_due(everything: bool = False) -> None:
                while to_fetch and (everything or to_fetch[0][0] <= time.monotonic()):
                    _, result = to_fetch.popleft()
                    assert result.digest is not None
                    wanted = Wanted(result.spec, result.digest, (result.worker,))
                    got = farm.fetch({result.job_id: wanted})[result.job_id]
                    if got.log is None or got.digest != result.digest:
                        ledger.fetches["failed"] += 1
                        ledger.lost_reasons.append(
                            f"{result.job_id}: log not fetched ({got.reason or got.digest})"
                        )
                    elif got.source == result.worker:
                        ledger.fetches["from its worker"] += 1
                    else:
                        ledger.fetches["simulated again"] += 1
                    if got.log is not None:
                        got.log.unlink(missing_ok=True)

            def take(result: EpisodeResult) -> None:
                ledger.record(result)
                if (
                    replicate_every
                    and result.digest is not None
                    and ledger.completed % replicate_every == 0
                ):
                    # The referee runs it again in this process; its log must be the worker's.
                    replication.validate(farm, [result], replicas, referee=referee)
                if result.log is not None:
                    result.log.unlink(missing_ok=True)  # hours of logs would fill the disk
                if (
                    fetch_every
                    and result.digest is not None
                    and result.scores is not None
                    and ledger.completed % fetch_every == 0
                ):
                    to_fetch.append((time.monotonic() + churn_seconds, result))

            def top_up() -> None:
                want = pending - farm.pending
                if want > 0:
                    farm.submit({job: job_spec(job_rng) for job in ledger.next_ids(want)})

            end = started + 60 * minutes
            next_churn = time.monotonic() + churn_seconds
            next_progress = time.monotonic() + PROGRESS_SECONDS
            last_result = time.monotonic()
            top_up()
            while time.monotonic() < end:
                for result in farm.results(timeout=0.2):
                    take(result)
                    last_result = time.monotonic()
                    if farm.pending <= pending // 2:
                        top_up()
                top_up()
                fetch_due()
                now = time.monotonic()
                if now >= next_churn:
                    next_churn = now + churn_seconds
                    if churn:
                        status = broker_status(farm)
                        busy = {w.name for w in status.workers if w.busy} if status else set()
                        pool.churn(busy)
                    else:
                        pool.reap()
                if now >= next_progress:
                    next_progress = now + PROGRESS_SECONDS
                    rate = ledger.completed / (now - started)
                    echo(
                        started,
                        f"{ledger.completed:,} done ({rate:.1f}/s), {farm.pending} pending, "
                        f"{len(pool.live)} workers, {pool.tally.starts} starts, "
                        f"{pool.tally.stops} stops, {pool.tally.kills} kills; "
                        f"last result {now - last_result:.1f} s ago",
                    )
            echo(started, f"draining {farm.pending} pending jobs")
            pool.reap()
            drained = time.monotonic()
            for result in farm.results(timeout=deadline * attempts + 30):
                take(result)
            fetch_due(everything=True)
            echo(started, f"drained in {time.monotonic() - drained:.1f} s")
            finished = time.monotonic()
            final_status = broker_status(farm)
            ledger.duplicate_results, ledger.ignored = farm.duplicates, farm.ignored
    finally:
        pool.close()
        broker.terminate()
        try:
            broker_code = broker.wait(STOP_SECONDS)
        except subprocess.TimeoutExpired:
            broker.kill()
            broker.wait()
        sampler.stop()
        if events is not None:
            pool.write_events(events)

    lines = [
        f"soak: {minutes:g} min, workers {workers_min}-{workers_max}, seed {seed}, "
        f"{pending} jobs in flight, "
        + (f"churn every {churn_seconds:g} s" if churn else "no churn")
        + f", warm-up {warm_up:.0f} s",
        *job_lines(ledger, warnings.counts, finished - started),
        pool.tally.line(),
        f"validation: {replicas.refereed} episodes run again here, "
        f"{replicas.disagreements} disagreements, {replicas.unsettled} unsettled, "
        f"dissenters: {', '.join(sorted(replicas.dissenters)) or 'none'}",
    ]
    if final_status is not None:
        lines.append(broker_line(final_status, broker_code))
    lines += memory_lines(sampler.samples, pool.resident, warm_up)
    lines += [f"  lost {reason}" for reason in ledger.lost_reasons[:10]]
    click.echo("\n".join(lines))
    if (
        ledger.lost
        or ledger.duplicated
        or pool.tally.died
        or pool.tally.hung
        or replicas.dissenters
    ):
        raise SystemExit(1)


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # so `finally` stops the farm
    main()
