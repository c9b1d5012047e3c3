"""The farm on one machine with no set-up: the broker inside this process, N worker processes.

Used by `analytic ... --local [--workers N]` and by the tests. The workers share the machine's
cores: each steps its batches on cores / N threads (at least one). One process, the default,
plans each trajectory and compiles each plant once, and its threads step the physics of its
batches on every core (worker.stepping); more processes pay those again, and gain only where the
GIL-bound part of a tick, small beside its physics, would hold the threads back.

Everything listens on loopback, on a port the kernel picked as free, so nothing collides with a
real farm on 7447.
"""

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence

from gainfarm.broker.service import Broker

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


def _await_workers(broker: Broker, processes: list[subprocess.Popen]) -> None:
    """Return once every worker has joined the broker. A run started sooner hands its first
    batch to whichever worker came first, all of it if it came alone, and the others idle."""
    deadline = time.monotonic() + READY_SECONDS
    while broker.status().worker_count < len(processes):
        if any(process.poll() is not None for process in processes):
            raise ConnectionError("a worker exited before joining")
        if time.monotonic() > deadline:
            raise ConnectionError(f"its workers did not join in {READY_SECONDS:.0f} s")
        time.sleep(0.05)


@contextlib.contextmanager
def farm_endpoints(connect: Sequence[str] = (), workers: int = 1) -> Iterator[list[str]]:
    """Where the farm is: the broker at `connect`, or else a local farm of `workers` processes
    started for the block."""
    if connect:
        yield list(connect)
        return
    with local_farm(workers) as endpoint:
        yield [endpoint]


@contextlib.contextmanager
def local_farm(workers: int = 1, lease_seconds: float = 60.0) -> Iterator[str]:
    """Run a broker and `workers` worker processes; yield the endpoint to connect to."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Broker([endpoint], lease_seconds=lease_seconds) as broker:
        threads = str(max(1, len(os.sched_getaffinity(0)) // workers))
        processes = [
            spawn_worker(endpoint, f"local-{index}", "warning", "--threads", threads)
            for index in range(workers)
        ]
        try:
            _await_workers(broker, processes)
            yield endpoint
        finally:
            stop_workers(processes)
