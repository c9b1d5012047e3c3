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
key, in turn, as fast as the farm takes them, without waiting for the answers. At SIGTERM it
prints `sent N answered M refused R`: the queries and samples it sent, the answers its queries
got, and how many of those were refusals.
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

from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.security import TlsIdentity
from tests.helpers import result_for

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


class Asker:
    """Floods keys with big queries and samples; counts the answers, on Zenoh's threads."""

    def __init__(self, session: zenoh.Session, payload: bytes):
        self.session, self.payload = session, payload
        self.sent = self.answered = self.refused = 0
        self._lock = threading.Lock()

    def _on_reply(self, reply: zenoh.Reply) -> None:
        with self._lock:
            self.answered += 1
            self.refused += reply.ok is None

    def flood(self, ask: list[str], put: list[str], stop: threading.Event) -> None:
        for kind, key in itertools.cycle([("ask", k) for k in ask] + [("put", k) for k in put]):
            if stop.is_set():
                return
            if kind == "ask":  # a callback: the next query goes out without waiting
                self.session.get(key, self._on_reply, payload=self.payload, timeout=10.0)
            else:
                block = zenoh.CongestionControl.BLOCK  # every one goes out
                self.session.put(key, self.payload, congestion_control=block)
            self.sent += 1
            if self.sent == 1:
                print("flooding", flush=True)


@dataclass
class Counts:
    """What a key flood sent and the answers it got, read when it stopped."""

    sent: int = 0
    answered: int = 0
    refused: int = 0


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
        _, sent, _, answered, _, refused = out.split()
        counts.sent, counts.answered, counts.refused = int(sent), int(answered), int(refused)
    finally:
        if flooder.poll() is None:
            flooder.kill()
            flooder.wait()


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
            time.sleep(1.0)  # answers to the last queries, if any come
        finally:
            session.close()
        print(f"sent {asker.sent} answered {asker.answered} refused {asker.refused}", flush=True)
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
