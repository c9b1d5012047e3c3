"""The farm on one machine with no set-up: a broker process and N worker processes.

Used by `analytic ... --local [--workers N]` and by the tests. By default one worker process per
core, each stepping its batches on one thread; N processes share the cores, cores / N threads
each (at least one). Processes, not threads: every world's step releases the GIL and takes it
back, so two threads of one process hand it to each other twice a tick per world, and a batch on
two threads ran 1.3x faster than on one where two processes run 2x (bench/episode_bench.py,
bench/main_job.py). A process costs its start (imports, each trajectory's plan, each plant's
model): a second or two, once.

The broker runs in a process of its own, not in this one: routing and scheduling every job took
about a third of the analytic process's CPU per evaluation (bench/analytic_cost.py), on the core
the run's own loop needs. Everything listens on loopback, on a port the kernel picked as free,
so nothing collides with a real farm on 7447.
"""

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence

from gainfarm.broker.status import query_status
from gainfarm.edges.transport import open_session
from gainfarm.schemas.wire import BadMessage

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


def _await(endpoint: str, broker: subprocess.Popen, workers: list[subprocess.Popen]) -> None:
    """Return once the broker answers, with every one of `workers` joined. Workers started
    before it answers would ask it for work before it serves, and say so; a run started before
    they join hands its first batch to whichever came first, all of it if it came alone, and the
    others idle."""
    deadline = time.monotonic() + READY_SECONDS
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
                if query_status(session, timeout=1.0).worker_count >= len(workers):
                    return
            except (ConnectionError, BadMessage):
                pass
            time.sleep(0.05)
    finally:
        if session is not None:
            session.close()


@contextlib.contextmanager
def farm_endpoints(connect: Sequence[str] = (), workers: int | None = None) -> Iterator[list[str]]:
    """Where the farm is: the broker at `connect`, or else a local farm of `workers` processes
    started for the block."""
    if connect:
        yield list(connect)
        return
    with local_farm(workers) as endpoint:
        yield [endpoint]


@contextlib.contextmanager
def local_farm(workers: int | None = None, lease_seconds: float = 60.0) -> Iterator[str]:
    """Run a broker process and `workers` worker processes (None: one per core); yield the
    endpoint to connect to. The broker stops last, once every worker has handed in its job."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cores = len(os.sched_getaffinity(0))
    workers = workers or cores
    broker = spawn_broker(endpoint, "--lease-seconds", str(lease_seconds))
    try:
        _await(endpoint, broker, [])
        threads = str(max(1, cores // workers))
        processes = [
            spawn_worker(endpoint, f"local-{index}", "warning", "--threads", threads)
            for index in range(workers)
        ]
        try:
            _await(endpoint, broker, processes)
            yield endpoint
        finally:
            stop_workers(processes)
    finally:
        stop_workers([broker])
