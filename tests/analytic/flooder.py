"""A junk flooder: puts big samples on a study's result keys as fast as the farm takes them, as a
red team did (issue 28). Every other sample is a well-formed Result for a job id a run is likely
to have pending (`g0000-c000-t0`...), its payload as long as that Result claims (the broker never
took it: only the job's lease holder's result is confirmed); the others have no attachment, a
garbage one, or a well-formed Result of another study.

    python -m tests.analytic.flooder ENDPOINT STUDY [--mib 64] [--junk-only]
        [--tls DIR --name WORKER]

With `--tls`, it connects with worker WORKER's certificate (one that holds no lease of the
study). It prints `flooding` once its first sample is out, and at SIGTERM the number it put.
"""

import argparse
import hashlib
import itertools
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

import zenoh

from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.security import TlsIdentity
from tests.helpers import result_for


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


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("endpoint")
    parser.add_argument("study")
    parser.add_argument("--mib", type=int, default=64)
    parser.add_argument("--tls", type=Path)
    parser.add_argument("--name", default="cobot-1")
    parser.add_argument("--junk-only", action="store_true", help="no forged results")
    options = parser.parse_args()
    identity = TlsIdentity(options.tls, "worker", options.name) if options.tls else None
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    payload = bytes(options.mib * 1024 * 1024)
    session = open_session("client", connect=[options.endpoint], identity=identity)
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
