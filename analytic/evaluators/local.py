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
the run's own loop needs.

Only this user's processes can reach the farm: its broker listens on a Unix socket in a directory
made for it, mode 0700 (the kernel refuses anyone else a connect() through it), and on no TCP
port, so nothing collides with a real farm on 7447 either. The directory goes when the farm stops.
The analytic side also takes results only from the workers the farm started (`names`, given to
FarmClient as `own_workers`): another process of this user that finds the socket and joins is
turned away by name (docs/security.md, "The local farm").

The broker and the workers start together (a worker imports for a second or more before it
connects, and the broker listens well before that; one that finds it not yet listening tries
again at once), and a run may submit as soon as the broker serves: its first jobs wait for the
workers in the broker's queue. Started one after the other, the processes' imports were most of
a local run's first 5 s.

A farm started for a run of an arm a robot description file describes (`--robot FILE`: the arm is
registered in the analytic process alone) hands its workers the same file (`robot_options`), so
that they serve that arm too; the shipped arms and installed plug-ins need nothing.
"""

import contextlib
import os
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence

from gainfarm import plugins

STOP_SECONDS = 15.0  # a worker finishes its episode before leaving; longer than that is a hang
# A worker imports MuJoCo and Zenoh before it joins: a few seconds on a loaded machine.
READY_SECONDS = 120.0
SOCKET = "broker.sock"  # the broker's socket, in the farm's own directory
# A Unix socket's path has room for 107 bytes (sun_path); a TMPDIR deeper than that leaves none.
SOCKET_PATH_BYTES = 100


def private_endpoint() -> tuple[str, str]:
    """A Unix-socket endpoint in a new directory of mode 0700 (tempfile.mkdtemp), and that
    directory: only this user (and root) may connect to a socket in it. In /tmp if TMPDIR is too
    deep for a socket's path."""
    directory = tempfile.mkdtemp(prefix="gainfarm-farm-")
    if len(os.fsencode(os.path.join(directory, SOCKET))) > SOCKET_PATH_BYTES:
        os.rmdir(directory)
        directory = tempfile.mkdtemp(prefix="gainfarm-farm-", dir="/tmp")
    return f"unixsock-stream/{os.path.join(directory, SOCKET)}", directory


def worker_names(count: int) -> tuple[str, ...]:
    """`local-N-SUFFIX`, SUFFIX random per farm: a process that has not read this one's command
    line cannot pose as one of its workers by guessing a name (`local-0`)."""
    suffix = secrets.token_hex(4)
    return tuple(f"local-{index}-{suffix}" for index in range(count))


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


def robot_options(robot: str | None) -> tuple[str, ...]:
    """A worker's options to serve `robot` (a name; None: whatever its jobs name): `--robot FILE`
    for an arm a description file describes (`gainfarm.models.described.source_of`), which a
    worker process knows only if told; nothing for a shipped arm or an installed plug-in."""
    if robot is None or robot in plugins.builtin_names(plugins.ROBOTS):
        return ()
    try:
        # start-up: the described arms' registry loads only for a farm of an arm not shipped
        from gainfarm.models.described import source_of
    except ImportError:  # an installation without description files: every arm is a plug-in
        return ()
    source = source_of(robot)
    return () if source is None else ("--robot", str(source))


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
    endpoint: str, broker: subprocess.Popen, workers: dict[str, subprocess.Popen], joined: bool
) -> None:
    """Return once the broker answers, with every one of `workers` (by name) joined if `joined`
    (by name: another process's joining does not count for one of them); without,
    a run's first jobs wait in the broker's queue for the workers to join, each asking for one
    job at first (a worker's first batch is one job per thread), so none takes a whole batch
    while the others idle."""
    # start-up: Zenoh, only once a local farm is started (not by `import gainfarm`'s tune)
    from gainfarm.broker.status import query_status
    from gainfarm.edges.transport import open_session
    from gainfarm.schemas.wire import BadMessage

    deadline = time.monotonic() + READY_SECONDS
    wanted = set(workers) if joined else set()
    session = None
    try:
        while True:
            if broker.poll() is not None:
                raise ConnectionError(f"its broker exited (status {broker.returncode})")
            if any(process.poll() is not None for process in workers.values()):
                raise ConnectionError("a worker exited before joining")
            if time.monotonic() > deadline:
                raise ConnectionError(f"its workers did not join in {READY_SECONDS:.0f} s")
            try:  # the broker may not listen yet: nothing to connect to, or no answer
                session = session or open_session("client", connect=[endpoint])
                status = query_status(session, timeout=1.0)
                if wanted <= {worker.name for worker in status.workers}:
                    return
            except (ConnectionError, BadMessage):
                pass
            time.sleep(0.02)
    finally:
        if session is not None:
            session.close()


@contextlib.contextmanager
def farm_endpoints(
    connect: Sequence[str] = (),
    workers: int | None = None,
    farm: "LocalFarm | None" = None,
    robot: str | None = None,
) -> Iterator[list[str]]:
    """Where the farm is: the broker at `connect`, or else `farm` (a local farm started
    already), or else a local farm of `workers` processes of `robot` started for the block. A
    local farm
    yields once its broker serves, its workers joining meanwhile, and begins to stop as the
    block ends (`LocalFarm.stop` waits for it)."""
    if connect:
        yield list(connect)
        return
    farm = farm or LocalFarm(workers, robot=robot)
    try:
        yield [farm.ready(joined=False)]
    finally:
        farm.stop(wait=False)


class LocalFarm:
    """A broker process and `workers` worker processes (None: one per core), all started at
    once, as the object is made: the broker listens well before a worker has imported what it
    runs, and a caller that imports and checks meanwhile finds the farm up. `endpoint`: its
    broker's Unix socket, in a directory of this user's alone (`private_endpoint`); `names`:
    its workers'. `robot`: the arm its runs are of, if known (its workers are told its
    description file, `robot_options`). Stop it with `stop` (or use it as a context manager)."""

    def __init__(
        self, workers: int | None = None, lease_seconds: float = 60.0, robot: str | None = None
    ):
        self.endpoint, self.directory = private_endpoint()
        cores = len(os.sched_getaffinity(0))
        count = workers or cores
        self.names = worker_names(count)
        self.workers: list[subprocess.Popen] = []
        self._stopping: threading.Thread | None = None
        self.broker: subprocess.Popen | None = None
        try:
            self.broker = spawn_broker(self.endpoint, "--lease-seconds", str(lease_seconds))
            threads = str(max(1, cores // count))
            arm = robot_options(robot)
            for name in self.names:
                self.workers.append(
                    spawn_worker(self.endpoint, name, "warning", "--threads", threads, *arm)
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
        assert self.broker is not None  # made with the object, or the object was not
        _await(self.endpoint, self.broker, dict(zip(self.names, self.workers, strict=True)), joined)
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
            try:
                stop_workers([self.broker] if self.broker is not None else [])
            finally:  # its socket and the socket's lock file: nothing of the farm is left
                shutil.rmtree(self.directory, ignore_errors=True)


@contextlib.contextmanager
def local_farm(
    workers: int | None = None, lease_seconds: float = 60.0, robot: str | None = None
) -> Iterator[str]:
    """Run a broker process and `workers` worker processes (None: one per core) of `robot`
    (LocalFarm); yield the endpoint to connect to once every worker has joined. The broker
    stops last, once every worker has handed in its job."""
    with LocalFarm(workers, lease_seconds, robot) as farm:
        yield farm.ready()
