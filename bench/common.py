"""What several benchmarks share: loopback endpoints, episode specs, percentiles and tables, and
stand-ins for the farm around a broker (an analytic client that only submits, workers that only
lease and report).

The stand-ins speak the farm's wire protocol as cheaply as they can (Submissions prebuilt as
bytes, replies read with json rather than pydantic): the load they put on a broker should cost as
little of the machine as it can, so that the broker's figures are the broker's.
"""

import contextlib
import json
import multiprocessing
import threading
import time
from collections.abc import Callable, Iterable, Sequence

import numpy as np
import zenoh

from analytic.farm import ANSWER_SECONDS, SUBMIT_CHUNK
from analytic.local import free_port
from broker.status import BrokerUnavailable, query_status
from schemas import EpisodeSpec, PDGains, TrajectorySpec, keys
from schemas.gains import DEFAULT_GAINS
from schemas.transport import open_session
from schemas.wire import (
    LEASE_HOLD_SECONDS,
    Job,
    JobStatus,
    LeaseRequest,
    Result,
    Submission,
    SubmitReply,
    Timings,
    decode,
)

SPAWN = multiprocessing.get_context("spawn")  # never fork a process that runs Zenoh threads


def loopback_endpoint() -> str:
    """An endpoint on loopback, on a port the kernel picked as free: never a farm's 7447."""
    return f"tcp/127.0.0.1:{free_port()}"


# --- episodes ----------------------------------------------------------------------------------


def scaled_gains(kp_factors: Sequence[float], kd_factors: Sequence[float]) -> PDGains:
    """The default gains, each joint's times its factor."""
    return PDGains(
        kp=tuple(gain * factor for gain, factor in zip(DEFAULT_GAINS.kp, kp_factors, strict=True)),
        kd=tuple(gain * factor for gain, factor in zip(DEFAULT_GAINS.kd, kd_factors, strict=True)),
    )


def episode_specs(count: int, duration: float) -> list[EpisodeSpec]:
    """`count` episodes of one spiral, gains from 0.8x to 1.2x the defaults: alike, not equal."""
    trajectory = TrajectorySpec(duration=duration)
    specs = []
    for index in range(count):
        factors = [0.8 + 0.4 * index / max(count - 1, 1)] * len(DEFAULT_GAINS.kp)
        specs.append(EpisodeSpec(gains=scaled_gains(factors, factors), trajectory=trajectory))
    return specs


# --- figures -----------------------------------------------------------------------------------


def percentile_ms(seconds: Iterable[float], percent: float) -> float:
    """A percentile of durations in seconds, in milliseconds."""
    return float(np.percentile(np.array(list(seconds)) * 1000, percent))


def print_table(header: Sequence[str], align: str, rows: Iterable[Sequence[str]]) -> None:
    """A Markdown table, as the README quotes it; `align` has an l or an r per column."""
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---:" if side == "r" else "---" for side in align) + "|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


# --- stand-ins for the farm around a broker ----------------------------------------------------


class FakeAnalytic:
    """An analytic client that only submits: it holds study `study`'s liveliness token and sends
    Submissions prebuilt as bytes. It evaluates nothing; its jobs' results go unread."""

    def __init__(self, endpoint: str, study: str):
        self.study = study
        self.session = open_session("client", connect=[endpoint])
        self._token = self.session.liveliness().declare_token(keys.alive_study(study))
        give_up = time.monotonic() + ANSWER_SECONDS
        while time.monotonic() < give_up:  # until the broker has seen the token, as FarmClient
            with contextlib.suppress(BrokerUnavailable):  # no answer yet: ask again
                if any(s.name == study for s in query_status(self.session, timeout=1.0).studies):
                    return
            time.sleep(0.02)
        raise ConnectionError(f"the broker at {endpoint} never opened study {study}")

    def submissions(self, count: int) -> list[bytes]:
        """`count` jobs of one valid episode spec, in Submissions of SUBMIT_CHUNK jobs (as big as
        FarmClient's)."""
        spec = episode_specs(1, 5.0)[0]
        return [
            Submission(
                study=self.study,
                jobs=[
                    Job(job_id=f"j{n}", spec=spec)
                    for n in range(start, min(start + SUBMIT_CHUNK, count))
                ],
            ).to_bytes()
            for start in range(0, count, SUBMIT_CHUNK)
        ]

    def submit(self, payload: bytes) -> None:
        for reply in self.session.get(keys.SUBMIT, payload=payload, timeout=ANSWER_SECONDS):
            if reply.ok is None or decode(SubmitReply, reply.ok.payload.to_bytes()).rejected:
                raise RuntimeError("the broker refused a submission")
            return
        raise RuntimeError("the broker did not answer a submission")

    def close(self) -> None:
        self._token.undeclare()
        self.session.close()


class NoopWorker:
    """Asks for a lease, runs the job (by default: does nothing) and puts an ok Result with an
    empty log, on a session it may share with other NoopWorkers."""

    def __init__(self, session: zenoh.Session, name: str, study: str):
        self.session = session
        self._token = session.liveliness().declare_token(keys.alive_worker(name))
        self._request = LeaseRequest(worker=name).to_bytes()
        self._result = Result(
            study=study,
            job_id="x",
            lease_id="x",
            worker=name,
            status=JobStatus.ok,
            episode_bytes=0,
            timings=Timings(simulate_s=0.0, encode_s=0.0),
        ).model_dump(mode="json")
        self.leases: list[tuple[float, float]] = []  # (monotonic time asked, latency s)
        self.runs: list[tuple[str, float, float]] = []  # (job id, start, end) of each job run
        self.completed = 0  # results put

    def serve(self, stop: threading.Event, run: Callable[[], None] | None = None) -> None:
        while not stop.is_set():
            asked = time.monotonic()
            lease = None
            for reply in self.session.get(
                keys.LEASE, payload=self._request, timeout=LEASE_HOLD_SECONDS + 5.0
            ):
                if reply.ok is None:
                    raise RuntimeError("the broker refused a lease request")
                lease = json.loads(reply.ok.payload.to_bytes())["lease"]
            if lease is None:  # no work now: ask again
                continue
            self.leases.append((asked, time.monotonic() - asked))
            job_id = lease["job"]["job_id"]
            if run is not None:
                started = time.monotonic()
                run()
                self.runs.append((job_id, started, time.monotonic()))
            result = {**self._result, "job_id": job_id, "lease_id": lease["lease_id"]}
            self.session.put(
                keys.result(lease["study"], job_id),
                b"",
                attachment=json.dumps(result).encode(),
                congestion_control=zenoh.CongestionControl.BLOCK,  # as CobotWorker: no drops
            )
            self.completed += 1

    def close(self) -> None:
        self._token.undeclare()
