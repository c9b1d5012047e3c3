"""A junk flooder: puts big samples on a study's result keys as fast as the farm takes them, as a
red team did (issue 28). Every other sample is a well-formed Result for a job id a run is likely
to have pending (`g0000-c000-t0`...), its payload as long as that Result claims (the broker never
took it: only the job's lease holder's result is confirmed); the others have no attachment, a
garbage one, or a well-formed Result of another study.

    python -m tests.analytic.flooder ENDPOINT STUDY [--mib 64] [--junk-only]
        [--tls DIR --name WORKER] [--ask KEY ...] [--put KEY ...]

With `--tls`, it connects with worker WORKER's certificate (one that holds no lease of the
study). It prints `flooding` once its first sample is out, and at SIGTERM the number it put.

With `--ask` or `--put` (each may be given again) it floods those keys instead (issue 47, item 4):
a query with a `--mib` MiB payload on each `--ask` key and a `--mib` MiB sample on each `--put`
key, in turn, as fast as the farm takes them, with IN_FLIGHT queries at most waiting for their
answers (each for QUERY_SECONDS): the flood costs each query's reassembly, not the link's
bandwidth, which a flood of unanswered queries at loopback speed would fill until the router
closes the link it cannot push to (Zenoh's `block/wait_before_close`). At SIGTERM it prints
`sent N answered M refused R timed-out T`: the queries and samples it sent, the answers its
queries got, how many of those were refusals, and the queries nobody answered in time.
"""

import argparse
import hashlib
import itertools
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import zenoh

from gainfarm.analytic.evaluators.local import spawn_worker, stop_workers
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.wire import Job, Result, Submission, SubmitReply, decode
from tests.helpers import query, result_for, short_spec, wait_for

ROOT = Path(__file__).resolve().parents[2]  # where `python -m tests.analytic.flooder` runs


def samples(study: str, payload: bytes, forge: bool) -> Iterator[tuple[str, bytes | None]]:
    """(job id, attachment) of each sample, in turn, forever; without `forge`, junk only."""
    digest = hashlib.sha256(payload).hexdigest()
    for number in itertools.count():
        guess = number // 2
        guessed = f"g{guess // 6 % 3:04d}-c{guess % 6:03d}-t0"
        forged = result_for(study, guessed, worker=f"forger-{number % 7}", lease_id="guessed")
        forged = forged.model_copy(update={"episode_bytes": len(payload), "digest": digest})
        kinds = (
            (guessed, forged.to_bytes()),
            (f"junk-{number}", None),
            (guessed, forged.to_bytes()),
            (f"junk-{number}", b"\xff" * 100),
            (guessed, forged.to_bytes()),
            (guessed, forged.model_copy(update={"study": "elsewhere"}).to_bytes()),
        )
        kind = kinds[number % len(kinds)]
        if forge or kind[1] != forged.to_bytes():
            yield kind


IN_FLIGHT = 4  # queries waiting for their answers at once
QUERY_SECONDS = 1.0  # how long each waits


class Asker:
    """Floods keys with big queries and samples; counts the answers, on Zenoh's threads."""

    def __init__(self, session: zenoh.Session, payload: bytes):
        self.session, self.payload = session, payload
        self.sent = self.answered = self.refused = self.timed_out = 0
        self._lock = threading.Lock()
        self._in_flight = threading.BoundedSemaphore(IN_FLIGHT)

    def _on_reply(self, reply: zenoh.Reply) -> None:
        # A query nobody answered in time is answered by the router: an error, "Timeout".
        if reply.err is not None and reply.err.payload.to_bytes() == b"Timeout":
            with self._lock:
                self.timed_out += 1
            return
        with self._lock:
            self.answered += 1
            self.refused += reply.ok is None

    def flood(self, ask: list[str], put: list[str], stop: threading.Event) -> None:
        for kind, key in itertools.cycle([("ask", k) for k in ask] + [("put", k) for k in put]):
            if stop.is_set():
                return
            if kind == "ask":  # a callback: the next query goes out without waiting for it
                while not self._in_flight.acquire(timeout=0.1):
                    if stop.is_set():
                        return
                done = zenoh.handlers.Callback(self._on_reply, self._in_flight.release)
                self.session.get(key, done, payload=self.payload, timeout=QUERY_SECONDS)
            else:
                block = zenoh.CongestionControl.BLOCK  # every one goes out
                self.session.put(key, self.payload, congestion_control=block)
            self.sent += 1
            if self.sent == 1:
                print("flooding", flush=True)


STUDY = "flooded"  # the study the key-flood tests run


class Study:
    """A study as an analytic process holds one: its token, and its results as they come."""

    def __init__(self, session: zenoh.Session):
        self.session = session
        self.results: dict[str, Result] = {}
        self._token = session.liveliness().declare_token(keys.alive_study(STUDY))
        self._inbox = session.declare_subscriber(keys.study_results(STUDY), self._on_result)
        wait_for(
            lambda: STUDY in {study.name for study in query_status(session).studies},
            what="the broker to open the study",
        )

    def _on_result(self, sample: zenoh.Sample) -> None:
        result = decode(Result, sample.attachment.to_bytes())
        self.results[result.job_id] = result

    def run(self, job_id: str) -> Result:
        """Submit a short job and wait for its result."""
        jobs = [Job(job_id=job_id, spec=short_spec(), keep_log=False)]
        submission = Submission(study=STUDY, jobs=jobs).to_bytes()
        ok, payload = query(self.session, keys.submit(STUDY), submission)
        assert ok and decode(SubmitReply, payload).queued == [job_id]
        wait_for(lambda: job_id in self.results, timeout=120, what=f"job {job_id}")
        return self.results[job_id]


@dataclass
class Counts:
    """What a key flood sent and the answers it got, read when it stopped."""

    sent: int = 0
    answered: int = 0
    refused: int = 0
    timed_out: int = 0


@contextmanager
def flooding_keys(
    endpoint: str, mib: int, ask: Sequence[str] = (), put: Sequence[str] = ()
) -> Iterator[Counts]:
    """The flooder in a process of its own, asking (with a `mib` MiB payload) on every `ask` key
    and putting on every `put` key until the block ends, seen flooding first; its counts are
    filled in once it has stopped."""
    options = [*(f"--ask={key}" for key in ask), *(f"--put={key}" for key in put)]
    command = [sys.executable, "-m", "tests.analytic.flooder", endpoint, "-", "--mib", str(mib)]
    flooder = subprocess.Popen(
        [*command, *options], cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True
    )
    counts = Counts()
    try:
        assert flooder.stdout is not None and flooder.stdout.readline() == "flooding\n"
        yield counts
        flooder.terminate()
        out, _ = flooder.communicate(timeout=30)
        figures = [int(word) for word in out.split()[1::2]]
        counts.sent, counts.answered, counts.refused, counts.timed_out = figures
    finally:
        if flooder.poll() is None:
            flooder.kill()
            flooder.wait()


@contextmanager
def farm_processes(endpoint: str, workers: Sequence[str], broker_log: Path) -> Iterator[None]:
    """A `broker start` process (its log written to `broker_log`) and a `worker start` process
    for each of `workers`, all joined before the block starts; stopped at its end. Processes of
    their own, as on a farm: Zenoh's threads are shared within a process, and a router blocked
    pushing a flood to a session in its own process can starve that session's reading."""
    command = ["-m", "gainfarm.broker", "start", "--listen", endpoint, "--log-level", "info"]
    with broker_log.open("w") as log:
        broker = subprocess.Popen(
            [sys.executable, *command], stdin=subprocess.DEVNULL, stderr=log, cwd=ROOT
        )
    farm = [spawn_worker(endpoint, name) for name in workers]
    try:
        wait_for(lambda: _joined(endpoint, workers), timeout=60, what="the broker and workers")
        yield
    finally:
        stop_workers(farm)
        broker.terminate()
        broker.wait(30)


def _joined(endpoint: str, workers: Sequence[str]) -> bool:
    """Whether the broker answers, with every one of `workers` joined."""
    try:
        with open_session("client", connect=[endpoint]) as session:
            status = query_status(session, timeout=1.0)
    except (ConnectionError, BrokerUnavailable):
        return False
    return set(workers) <= {worker.name for worker in status.workers}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("endpoint")
    parser.add_argument("study")
    parser.add_argument("--mib", type=int, default=64)
    parser.add_argument("--tls", type=Path)
    parser.add_argument("--name", default="cobot-1")
    parser.add_argument("--junk-only", action="store_true", help="no forged results")
    parser.add_argument("--ask", action="append", default=[], help="query KEY with the payload")
    parser.add_argument("--put", action="append", default=[], help="put the payload on KEY")
    options = parser.parse_args()
    identity = TlsIdentity(options.tls, "worker", options.name) if options.tls else None
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    payload = bytes(options.mib * 1024 * 1024)
    session = open_session("client", connect=[options.endpoint], identity=identity)
    if options.ask or options.put:
        asker = Asker(session, payload)
        try:
            asker.flood(options.ask, options.put, stop)
            time.sleep(2 * QUERY_SECONDS)  # the last queries answered, or timed out
        finally:
            session.close()
        counts = f"sent {asker.sent} answered {asker.answered} refused {asker.refused}"
        print(f"{counts} timed-out {asker.timed_out}", flush=True)
        return
    put = 0
    try:
        for job_id, attachment in samples(options.study, payload, forge=not options.junk_only):
            if stop.is_set():
                break
            session.put(
                keys.result(options.study, job_id),
                payload,
                attachment=attachment,
                congestion_control=zenoh.CongestionControl.BLOCK,  # every one goes out
            )
            put += 1
            if put == 1:
                print("flooding", flush=True)
    finally:
        session.close()
        print(put, flush=True)


if __name__ == "__main__":
    main()
