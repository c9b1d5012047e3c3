"""What several benchmarks share: loopback endpoints, episode specs, percentiles and tables, and
stand-ins for the farm around a broker (an analytic client that submits and confirms results but
evaluates nothing, workers that only lease, hand in and report).

The stand-ins speak the farm's wire protocol (schemas.wire.PROTOCOL_VERSION) as cheaply as they
can (Submissions prebuilt as bytes, replies read with json rather than pydantic): the load they
put on a broker should cost as little of the machine as it can, so that the broker's figures are
the broker's.
They ask the broker as the farm's own clients do (gainfarm.edges.ask), so the broker serves the same
queries as it does for a FarmClient and a CobotWorker.
"""

import contextlib
import hashlib
import json
import multiprocessing
import queue
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterable, Sequence

import numpy as np
import zenoh

from gainfarm.analytic.evaluators.farm import ANSWER_SECONDS, CONFIRM_BATCH, SUBMIT_CHUNK
from gainfarm.analytic.evaluators.local import free_port, spawn_broker
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.ask import Answer, ask
from gainfarm.edges.parts import reply_part
from gainfarm.edges.transport import open_session
from gainfarm.schemas import EpisodeSpec, PDGains, TrajectorySpec, keys
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.wire import (
    LEASE_HOLD_SECONDS,
    PROTOCOL_VERSION,
    Job,
    JobStatus,
    Result,
    Submission,
    SubmitReply,
    Timings,
    WireScores,
    decode,
)

SPAWN = multiprocessing.get_context("spawn")  # never fork a process that runs Zenoh threads
BROKER_STARTUP_SECONDS = 20.0  # for a broker process to listen


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


def _answered(answer: Answer | None, what: str) -> bytes:
    """The payload of the broker's answer; RuntimeError if it refused or did not answer."""
    if answer is None:
        raise RuntimeError(f"the broker did not answer {what}")
    if answer.payload is None:
        raise RuntimeError(f"the broker refused {what}: {answer.error}")
    return answer.payload


class FakeAnalytic:
    """An analytic client that submits and confirms, and evaluates nothing: it holds study
    `study`'s liveliness token, sends Submissions prebuilt as bytes, and, as FarmClient does,
    checks each result's digest and asks the broker which ones it took, in batches of whatever
    arrived while the previous question was out (at most CONFIRM_BATCH)."""

    def __init__(self, endpoint: str, study: str):
        self.study = study
        self.confirmed = 0  # results the broker confirmed
        self.unconfirmed = 0  # results it did not (there should be none)
        self.bad_digests = 0
        self.rounds: list[tuple[int, float]] = []  # (results asked about, round trip s)
        self.waits: list[float] = []  # s from a result's arrival to its confirmation
        self._key = keys.confirm(study)
        self._arrivals: queue.SimpleQueue[tuple[float, dict]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self.session = open_session("client", connect=[endpoint])
        self._subscriber = self.session.declare_subscriber(
            keys.study_results(study), self._on_result
        )
        self._token = self.session.liveliness().declare_token(keys.alive_study(study))
        self._confirmer = threading.Thread(target=self._confirm, name="fake-analytic-confirm")
        self._confirmer.start()
        give_up = time.monotonic() + ANSWER_SECONDS
        while time.monotonic() < give_up:  # until the broker has seen the token, as FarmClient
            with contextlib.suppress(BrokerUnavailable):  # no answer yet: ask again
                if any(s.name == study for s in query_status(self.session, timeout=1.0).studies):
                    return
            time.sleep(0.02)
        self.close()
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
        answer = ask(self.session, keys.submit(self.study), payload, ANSWER_SECONDS)
        reply = decode(SubmitReply, _answered(answer, "a submission"))
        if reply.rejected:
            raise RuntimeError(f"the broker rejected jobs: {reply.rejected[0].reason}")
        if reply.deferred:
            raise RuntimeError(f"the broker deferred {len(reply.deferred)} jobs: queue full")

    def close(self) -> None:
        self._stop.set()
        self._confirmer.join()
        self._token.undeclare()
        self.session.close()

    def _on_result(self, sample: zenoh.Sample) -> None:
        result = json.loads(sample.attachment.to_bytes())
        if hashlib.sha256(sample.payload.to_bytes()).hexdigest() != result["digest"]:
            self.bad_digests += 1
            return
        self._arrivals.put((time.monotonic(), result))

    def _confirm(self) -> None:
        while not self._stop.is_set():
            try:
                batch = [self._arrivals.get(timeout=0.1)]
            except queue.Empty:
                continue
            with contextlib.suppress(queue.Empty):
                while len(batch) < CONFIRM_BATCH:
                    batch.append(self._arrivals.get_nowait())
            request = {
                "protocol": PROTOCOL_VERSION,
                "study": self.study,
                "job_ids": [result["job_id"] for _, result in batch],
            }
            asked = time.monotonic()
            answer = ask(self.session, self._key, json.dumps(request).encode(), ANSWER_SECONDS)
            accepted = json.loads(_answered(answer, "a confirmation"))["accepted"]
            answered = time.monotonic()
            self.rounds.append((len(batch), answered - asked))
            taken = {(a["job_id"], a["lease_id"], a["worker"], a["digest"]) for a in accepted}
            for arrived, result in batch:
                fields = (result["job_id"], result["lease_id"], result["worker"], result["digest"])
                if fields in taken:
                    self.confirmed += 1
                    self.waits.append(answered - arrived)
                else:
                    self.unconfirmed += 1

    def wait_confirmed(self, count: int, timeout: float = ANSWER_SECONDS) -> None:
        """Wait until `count` results were confirmed; RuntimeError if they are not in time."""
        give_up = time.monotonic() + timeout
        while self.confirmed < count:
            if time.monotonic() > give_up:
                raise RuntimeError(f"{self.confirmed} of {count} results confirmed")
            time.sleep(0.01)


EMPTY_LOG = b""  # what a NoopWorker sends as an episode log
NOOP_SCORES = WireScores(  # and the scores it claims for it
    f_acc=0.01,
    f_t=0.1,
    max_error=0.02,
    saturated_fraction=0.0,
    diverged=False,
    ticks=1,
    torque_step=0.01,
    speed=0.5,
    chatter=0.001,
    lag=0.006,
    damping=0.05,
)


class NoopWorker:
    """Asks for up to `batch` leases, runs each job (by default: does nothing), hands in ok
    Results of `log` (by default an empty one) with its next request and puts each one the
    broker takes, without its log, on a session it may share with other NoopWorkers; it serves
    `log` in parts on its log keys, as a worker serves the logs it keeps. With a real episode's
    log (and jobs that all name its spec), it is a cobot that skips the simulation."""

    def __init__(
        self,
        session: zenoh.Session,
        name: str,
        study: str,
        log: bytes = EMPTY_LOG,
        scores: WireScores = NOOP_SCORES,
        batch: int = 1,
    ):
        self.session = session
        self._token = session.liveliness().declare_token(keys.alive_worker(name))
        self._logs = session.declare_queryable(
            keys.worker_logs(name), lambda query: reply_part(query, log)
        )
        self._lease_key = keys.lease(name)
        self._name = name
        self._batch = batch
        self._result = Result(
            study=study,
            job_id="x",
            lease_id="x",
            worker=name,
            status=JobStatus.ok,
            episode_bytes=len(log),
            digest=hashlib.sha256(log).hexdigest(),
            timings=Timings(simulate_s=0.0, encode_s=0.0),
            scores=scores,
        ).model_dump(mode="json")
        self.leases: list[tuple[float, float]] = []  # (monotonic time asked, latency s)
        self.hand_ins: list[float] = []  # s from handing results in to the broker's verdicts
        self.runs: list[tuple[str, float, float]] = []  # (job id, start, end) of each job run
        self.completed = 0  # results the broker took, and put
        self.refused = 0  # results the broker did not take

    def serve(self, stop: threading.Event, run: Callable[[], None] | None = None) -> None:
        done: list[tuple[dict, dict]] = []  # (lease, result) to hand in with the next request
        while not stop.is_set() or done:
            want = 0 if stop.is_set() else self._batch
            request = {
                "protocol": PROTOCOL_VERSION,
                "worker": self._name,
                "want": want,
                "results": [result for _, result in done],
            }
            asked = time.monotonic()
            answer = ask(
                self.session,
                self._lease_key,
                json.dumps(request).encode(),
                LEASE_HOLD_SECONDS + 5.0,
            )
            reply = json.loads(_answered(answer, "a lease request"))
            answered = time.monotonic()
            if done:
                self.hand_ins.append(answered - asked)
            self._send(done, reply["verdicts"])
            done = []
            if reply["leases"]:
                self.leases.append((asked, answered - asked))
            for lease in reply["leases"]:
                job_id = lease["job"]["job_id"]
                if run is not None:
                    started = time.monotonic()
                    run()
                    self.runs.append((job_id, started, time.monotonic()))
                done.append(
                    (lease, {**self._result, "job_id": job_id, "lease_id": lease["lease_id"]})
                )

    def _send(self, done: list[tuple[dict, dict]], verdicts: list[dict]) -> None:
        taken = {(v["job_id"], v["lease_id"]) for v in verdicts if v["accepted"]}
        for lease, result in done:
            if (result["job_id"], result["lease_id"]) not in taken:
                self.refused += 1
                continue
            self.session.put(
                keys.result(lease["study"], result["job_id"]),
                b"",  # its log is fetched in parts, if it is wanted
                attachment=json.dumps(result).encode(),
                congestion_control=zenoh.CongestionControl.BLOCK,  # as CobotWorker: no drops
            )
            self.completed += 1

    def close(self) -> None:
        self._logs.undeclare()
        self._token.undeclare()


# --- the broker --------------------------------------------------------------------------------


@contextlib.contextmanager
def broker_process(endpoint: str, queued: int):
    """The real broker, alone in its process."""
    process = spawn_broker(
        endpoint,
        "--max-queued",
        str(max(queued, 100_000)),
        "--max-queued-per-study",
        str(max(queued, 20_000)),
    )
    try:
        port = int(endpoint.rsplit(":", 1)[1])
        give_up = time.monotonic() + BROKER_STARTUP_SECONDS
        while True:  # until it listens
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
                break
            except OSError:
                if time.monotonic() > give_up or process.poll() is not None:
                    raise RuntimeError(f"the broker did not listen on {endpoint}") from None
                time.sleep(0.1)
        yield process
    finally:
        process.terminate()
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
