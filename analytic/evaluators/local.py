"""The farm on one machine with no set-up: a broker process and N worker processes.

Used by `analytic ... --local [--workers N]` and by the tests. By default one worker process per
core, each stepping its batches on one thread; N processes share the cores, cores / N threads
each (at least one). Processes, not threads, measured: a worker's stacks of episodes step on a
mujoco.batch.Batch, which takes the GIL back once a tick per stack, and two threads of one
process step a batch 1.67x faster than one; yet `analytic start --pop 30 --evaluations 600` ran
in 21.7-26.8 s on two processes of one thread against 34.9-37.0 s on one process of two
(docs/performance.md, "The main job against a plain pool and Optuna"). A process costs its
start (imports, each trajectory's plan, each plant's model): a second or two, once, while the
analytic starts (below).

The broker runs in a process of its own, not in this one: routing and scheduling every job took
about a third of the analytic process's CPU per evaluation (bench/analytic_cost.py), on the core
the run's own loop needs. Everything listens on loopback, on a port the kernel picked as free,
so nothing collides with a real farm on 7447.

The broker and the workers start together (a worker imports for a second or more before it
connects, and the broker listens well before that; one that finds it not yet listening tries
again at once), and a run may submit as soon as the broker serves: its first jobs wait for the
workers in the broker's queue. Started one after the other, the processes' imports were most of
a local run's first 5 s.
"""

import contextlib
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence

STOP_SECONDS = 15.0  # a worker finishes its episode before leaving; longer than that is a hang
# A worker imports MuJoCo and Zenoh before it joins: a few seconds on a loaded machine.
READY_SECONDS = 120.0


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def spawn_worker(
    endpoint: str, name: str, log_level: str = "warning", *options: str
) -> subprocess.Popen:
    """`worker start` in a process of its own; `options`: more of its command-line options."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "gainfarm.worker",
            "start",
            "--connect",
            endpoint,
            "--name",
            name,
            "--log-level",
            log_level,
            *options,
        ],
        stdin=subprocess.DEVNULL,
    )


def stop_workers(workers: list[subprocess.Popen]) -> None:
    """SIGTERM every worker, wait for each to hand in its job, SIGKILL those that do not."""
    for worker in workers:
        worker.terminate()
    for worker in workers:
        try:
            worker.wait(STOP_SECONDS)
        except subprocess.TimeoutExpired:
            worker.kill()
            worker.wait()


def spawn_broker(endpoint: str, *options: str, log_level: str = "warning") -> subprocess.Popen:
    """`broker start` in a process of its own, listening on `endpoint`; `options`: more of its
    command-line options."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "gainfarm.broker",
            "start",
            "--listen",
            endpoint,
            "--log-level",
            log_level,
            *options,
        ],
        stdin=subprocess.DEVNULL,
    )


def _await(
    endpoint: str, broker: subprocess.Popen, workers: list[subprocess.Popen], joined: bool
) -> None:
    """Return once the broker answers, with every one of `workers` joined if `joined`; without,
    a run's first jobs wait in the broker's queue for the workers to join, each asking for one
    job at first (a worker's first batch is one job per thread), so none takes a whole batch
    while the others idle."""
    from gainfarm.broker.status import query_status
    from gainfarm.edges.transport import open_session
    from gainfarm.schemas.wire import BadMessage

    deadline = time.monotonic() + READY_SECONDS
    wanted = len(workers) if joined else 0
    session = None
    try:
        while True:
            if broker.poll() is not None:
                raise ConnectionError(f"its broker exited (status {broker.returncode})")
            if any(process.poll() is not None for process in workers):
                raise ConnectionError("a worker exited before joining")
            if time.monotonic() > deadline:
                raise ConnectionError(f"its workers did not join in {READY_SECONDS:.0f} s")
            try:  # the broker may not listen yet: nothing to connect to, or no answer
                session = session or open_session("client", connect=[endpoint])
                if query_status(session, timeout=1.0).worker_count >= wanted:
                    return
            except (ConnectionError, BadMessage):
                pass
            time.sleep(0.02)
    finally:
        if session is not None:
            session.close()


@contextlib.contextmanager
def farm_endpoints(
    connect: Sequence[str] = (), workers: int | None = None, farm: "LocalFarm | None" = None
) -> Iterator[list[str]]:
    """Where the farm is: the broker at `connect`, or else `farm` (a local farm started
    already), or else a local farm of `workers` processes started for the block. A local farm
    yields once its broker serves, its workers joining meanwhile, and begins to stop as the
    block ends (`LocalFarm.stop` waits for it)."""
    if connect:
        yield list(connect)
        return
    farm = farm or LocalFarm(workers)
    try:
        yield [farm.ready(joined=False)]
    finally:
        farm.stop(wait=False)


class LocalFarm:
    """A broker process and `workers` worker processes (None: one per core), all started at
    once, as the object is made: the broker listens well before a worker has imported what it
    runs, and a caller that imports and checks meanwhile finds the farm up. Stop it with
    `stop` (or use it as a context manager)."""

    def __init__(self, workers: int | None = None, lease_seconds: float = 60.0):
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        cores = len(os.sched_getaffinity(0))
        count = workers or cores
        self.broker = spawn_broker(self.endpoint, "--lease-seconds", str(lease_seconds))
        self.workers: list[subprocess.Popen] = []
        self._stopping: threading.Thread | None = None
        try:
            threads = str(max(1, cores // count))
            for index in range(count):
                self.workers.append(
                    spawn_worker(self.endpoint, f"local-{index}", "warning", "--threads", threads)
                )
        except BaseException:
            self.stop()
            raise

    def __enter__(self) -> "LocalFarm":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def ready(self, joined: bool = True) -> str:
        """The endpoint to connect to, once the broker answers (and, if `joined`, every worker
        has joined it); ConnectionError if a process exits first, or it takes READY_SECONDS."""
        _await(self.endpoint, self.broker, self.workers, joined)
        return self.endpoint

    def stop(self, wait: bool = True) -> None:
        """Stop the workers (each hands in its job first), then the broker. With `wait` False,
        only begin to: the processes stop on a thread of their own while the caller goes on
        (a run's report is drawn meanwhile); a later `stop()` waits for them."""
        if self._stopping is None:
            self._stopping = threading.Thread(target=self._stop, name="local-farm-stop")
            self._stopping.start()
        if wait:
            self._stopping.join()

    def _stop(self) -> None:
        try:
            stop_workers(self.workers)
        finally:
            stop_workers([self.broker])


@contextlib.contextmanager
def local_farm(workers: int | None = None, lease_seconds: float = 60.0) -> Iterator[str]:
    """Run a broker process and `workers` worker processes (None: one per core); yield the
    endpoint to connect to once every worker has joined. The broker stops last, once every
    worker has handed in its job."""
    with LocalFarm(workers, lease_seconds) as farm:
        yield farm.ready()
