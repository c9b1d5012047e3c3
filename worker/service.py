"""The sim-cobot on the wire: connect, hold a liveliness token, ask for a batch of work when free,
run it, hand its results in to the broker with the next request and send each one the broker took
to its study. One process is one cobot.

A batch is about BATCH_SECONDS of work (one job when jobs are long): short jobs then cost the broker
one query per batch instead of two per job, and its episodes step together (worker.stepping), on
the worker's `threads`.

A result's sample never carries its episode log: the worker keeps every log it made in memory (a
LogStore, bounded: the least recently used go first) and serves it by its digest, in parts of at
most PART_BYTES, to the study whose job made it, on keys.log. A job that says `keep_log` is one
whose study fetches the log as soon as the broker confirms the result.

Its one session serves (the log queryable, the token) and takes in no message larger than a wire
message (SERVING_SESSION_BYTES): a big query on its log keys is dropped by Zenoh on the way. A
model, which may be larger, is fetched on it in parts (gainfarm/edges/parts.py; docs/security.md,
"Junk on every key").
"""

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import zenoh

from gainfarm.edges.ask import ask
from gainfarm.edges.parts import fetch_parts, reply_part
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session, token_held
from gainfarm.models.dynamics import MAX_FILE_BYTES, DynamicsModel, digest
from gainfarm.schemas import keys
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.wire import (
    LEASE_HOLD_SECONDS,
    MAX_BATCH,
    BadMessage,
    Lease,
    LeaseReply,
    LeaseRequest,
    Result,
    Verdict,
    decode,
)
from gainfarm.worker.feedforward import ModelCache
from gainfarm.worker.job import Simulate, execute, execute_batch
from gainfarm.worker.logstore import LogStore

log = logging.getLogger("gainfarm.worker")

ANSWER_MARGIN = 5.0  # s beyond the broker's longest hold before a lease request counts as lost
RETRY_SECONDS = 1.0  # pause after a broker that did not answer or answered with an error
ANSWER_SECONDS = 10.0  # how long a study has to answer a model fetch
# Work asked for at once: results wait for their batch about this long. Long enough for batches
# of some 8 episodes per thread (where stepping them together has paid most of what it pays).
BATCH_SECONDS = 1.0
# Bytes of kept episode logs: some 20 of 120 s, hundreds of short ones. A study that keeps every
# log (`--keep all`) fetches each as soon as its result is confirmed, a moment after it is made:
# the store then holds hundreds of seconds of this worker's output by the time a log goes.
LOG_MEMORY = 512 * 2**20


class NameTaken(RuntimeError):
    pass


@dataclass(frozen=True)
class HandIn:
    """A leased job this worker ran, waiting to be handed in."""

    lease: Lease
    result: Result
    content: bytes  # the episode log
    give_up: float  # monotonic time its lease expires: a result the broker never took is dropped


def fetch_model(session: zenoh.Session, study: str, wanted: str) -> bytes | None:
    """The bytes of the model hashing to `wanted`, from whoever serves them, in parts, or None.
    The content hash is the trust: unlike the broker's answers, these may come from any process,
    and bytes that hash to anything else (or are too large to be a model, or come in parts that
    break the rules: schemas.parts) are ignored."""
    key = keys.model(study, wanted)
    try:
        raw = fetch_parts(session, key, MAX_FILE_BYTES, ANSWER_SECONDS, everyone=True)
    except BadMessage as error:
        log.warning("ignored a model on %s: %s", key, error)
        return None
    except zenoh.ZError as error:  # e.g. the session closed while it asked
        log.warning("cannot fetch model %s: %s", wanted[:12], error)
        return None
    if raw is None:
        return None
    if digest(raw) != wanted:
        log.warning("ignored a model on %s that hashes to %s", key, digest(raw)[:12])
        return None
    return raw


class CobotWorker:
    def __init__(
        self,
        connect: Sequence[str],
        name: str,
        identity: TlsIdentity | None = None,
        models: ModelCache | None = None,
        log_memory: int = LOG_MEMORY,
        simulate: Simulate | None = None,
        threads: int = 1,
        on_idle: Callable[[], None] | None = None,
    ):
        """`log_memory`: bytes of episode logs kept for the studies to fetch. `simulate` runs an
        episode in place of MuJoCo, one at a time (only for simulated workers:
        bench/campaign.py --simulated). `threads`: threads stepping a batch's episodes.
        `on_idle`: called once, the first time the broker has no work for it (what a first job
        would load can load then, rather than in that job)."""
        request = LeaseRequest(worker=name)  # validates the name: it becomes a key chunk
        self.name = request.worker
        self.models = models if models is not None else ModelCache()
        self.logs = LogStore(log_memory)
        self._simulate = simulate
        self.threads = threads
        self._on_idle = on_idle
        self._idle = False  # waiting for work, nothing to hand in (set by the serving thread)
        self._job_seconds: float | None = None  # a recent job's share of its batch's wall time
        self.jobs_done = 0
        self.refused = 0  # results the broker did not take (e.g. the lease had gone elsewhere)
        self.session = open_session(
            "client", connect=connect, identity=identity, max_message_bytes=SERVING_SESSION_BYTES
        )
        try:
            if token_held(self.session, keys.alive_worker(name)):
                raise NameTaken(f"a worker named {name!r} is already connected to this farm")
            self._token = self.session.liveliness().declare_token(keys.alive_worker(name))
            # Undeclared when the session closes.
            self._logs_queryable = self.session.declare_queryable(
                keys.worker_logs(self.name), self._on_log_query
            )
        except BaseException:
            self.session.close()
            raise

    def broker_serves(self) -> bool:
        """Whether the farm's broker answers (its status): its router may listen before it
        serves, and a worker that asked for work then would wait a second to ask again."""
        return ask(self.session, keys.STATUS, timeout=ANSWER_SECONDS) is not None

    def __enter__(self) -> "CobotWorker":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if not self.session.is_closed():
            self._token.undeclare()
            self.session.close()

    def serve(self, stop: threading.Event, max_jobs: int | None = None) -> int:
        """Serve until `stop` is set (the batch in progress is finished and handed in first)."""
        ran: list[HandIn] = []
        while True:
            want = 0 if stop.is_set() else self._want(max_jobs, len(ran))
            if want == 0 and not ran:
                return self.jobs_done
            self._idle = not ran  # asking for work with nothing to hand in: the broker holds it
            try:
                reply = self._ask_for_work(want, ran)
            finally:
                self._idle = False
            if reply is None:
                now = time.monotonic()
                for lost in (r for r in ran if r.give_up <= now or stop.is_set()):
                    log.warning(
                        "%s/%s: no broker took the result", lost.lease.study, lost.lease.job.job_id
                    )
                ran = [r for r in ran if r.give_up > now and not stop.is_set()]
                stop.wait(RETRY_SECONDS)
                continue
            self._send(ran, reply.verdicts)
            if not reply.leases and self._on_idle is not None:
                self._on_idle, on_idle = None, self._on_idle
                on_idle()
            ran = self._run(reply.leases)

    def serve_until(self, stop: threading.Event) -> int:
        """`serve` on a thread of its own until `stop` is set, as a signal's handler sets it.
        Python runs a signal's handler in the main thread only, once it is back from Zenoh: a
        worker waiting for work, its request held by the broker (up to LEASE_HOLD_SECONDS),
        heard a SIGTERM only when the hold ended. Here the main thread waits on `stop` itself,
        and lets the held request go at once (`_leave`): a local farm stops in a moment, not a
        second, when its run ends."""
        done: list[int] = []
        failed: list[BaseException] = []

        def serve() -> None:
            try:
                done.append(self.serve(stop))
            except BaseException as error:  # re-raised in the main thread
                failed.append(error)

        thread = threading.Thread(target=serve, name="serve")
        thread.start()
        while thread.is_alive():
            if stop.wait(0.5):
                self._leave()
                thread.join()
        if failed:
            raise failed[0]
        return done[0]

    def _leave(self) -> None:
        """If the serving thread waits for work with nothing to hand in, ask for none: the
        broker answers the request it holds with no work (a worker's new request replaces its
        held one), and the thread, told to stop, returns. A batch being run is left to finish
        and be handed in."""
        if self._idle:
            request = LeaseRequest(worker=self.name, want=0)
            ask(self.session, keys.lease(self.name), request.to_bytes(), ANSWER_MARGIN)

    def _want(self, max_jobs: int | None, waiting: int) -> int:
        """Leases to ask for: about BATCH_SECONDS of work at the pace of the last jobs (at
        first, one per thread)."""
        pace = self._job_seconds
        want = self.threads if pace is None else round(BATCH_SECONDS / pace)
        want = max(1, min(MAX_BATCH, want))
        return want if max_jobs is None else max(0, min(want, max_jobs - self.jobs_done - waiting))

    def _run(self, leases: list[Lease]) -> list[HandIn]:
        if not leases:
            return []
        started, started_at = time.perf_counter(), time.monotonic()
        if self._simulate is not None:
            ran = [
                execute(lease, self.name, self._model_of(lease), self._simulate) for lease in leases
            ]
        else:
            ran = execute_batch(leases, self.name, self._model_of, self.threads)
        took = (time.perf_counter() - started) / len(leases)
        pace = self._job_seconds
        self._job_seconds = took if pace is None else 0.8 * pace + 0.2 * took
        return [
            HandIn(lease, result, content, started_at + lease.expires_in)
            for lease, (result, content) in zip(leases, ran, strict=True)
        ]

    def _send(self, ran: list[HandIn], verdicts: list[Verdict]) -> None:
        """Send each result the broker took to its study; keep its log here, to be fetched."""
        verdict_of = {(v.job_id, v.lease_id): v for v in verdicts}
        for item in ran:
            result, content = item.result, item.content
            verdict = verdict_of.get((result.job_id, result.lease_id))
            if verdict is None or not verdict.accepted:
                self.refused += 1
                reason = "no verdict on it" if verdict is None else verdict.reason
                log.log(
                    logging.INFO if _no_ones_fault(reason) else logging.WARNING,
                    "%s/%s: the broker did not take the result: %s",
                    result.study,
                    result.job_id,
                    reason,
                )
                continue
            if result.scores is not None:  # it ran: not failed, nor refused
                # Kept before the result goes out: a study may fetch the log the moment it arrives.
                if len(content) > self.logs.max_bytes:
                    log.warning(
                        "%s/%s: its %d-byte log is larger than the log memory; not kept",
                        result.study,
                        result.job_id,
                        len(content),
                    )
                self.logs.keep(result.study, result.digest, content)
            self.session.put(
                keys.result(result.study, result.job_id),
                b"",  # the log is fetched in parts (keys.log)
                attachment=result.to_bytes(),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            self.jobs_done += 1
            log.info(
                "%s/%s: %s in %.3f s",
                result.study,
                result.job_id,
                result.status.value,
                result.timings.simulate_s + result.timings.encode_s,
            )

    def _on_log_query(self, query: zenoh.Query) -> None:
        """Serve a kept log: gainfarm/study/{study}/log/{worker}/{digest}?part=N → that part of
        its bytes (schemas.parts), to that study only. Runs on Zenoh's threads; whatever the
        query, it answers and never raises."""
        try:
            key = str(query.key_expr)
            chunks = key.split("/")
            study, digest = (chunks[2], chunks[5]) if len(chunks) == 6 else ("", "")
            if key != keys.log(study, self.name, digest):  # e.g. another worker's, or gainfarm/**
                query.reply_err(f"not a log key of worker {self.name}: {_shown(key)}")
                return
            content = self.logs.get(study, digest)
            if content is None:
                query.reply_err(f"no such log: {_shown(key)} (never made, or no longer kept)")
                return
            reply_part(query, content)
        except Exception as error:  # a bad query must not take the worker's queryable down
            log.warning("a log query failed: %s", _shown(f"{type(error).__name__}: {error}"))
            with contextlib.suppress(Exception):  # e.g. the query had already been answered
                query.reply_err("this worker could not answer the query")

    def _model_of(self, lease: Lease) -> Callable[[str], DynamicsModel]:
        """The job's feed-forward model by its digest, fetched from its study the first time."""

        def model(wanted: str) -> DynamicsModel:
            return self.models.model(
                wanted,
                lambda _: fetch_model(self.session, lease.study, wanted),
            )

        return model

    def _ask_for_work(self, want: int, ran: list[HandIn]) -> LeaseReply | None:
        """Hand in `ran`'s results and ask for `want` leases: the broker's answer, or None if
        there was no usable one (the same results are handed in again: the broker takes a
        repeated hand-in as it took the first)."""
        key = keys.lease(self.name)
        request = LeaseRequest.model_construct(  # validated: its name, once; its results, made here
            worker=self.name, want=want, results=[r.result for r in ran]
        )
        answer = ask(self.session, key, request.to_bytes(), LEASE_HOLD_SECONDS + ANSWER_MARGIN)
        if answer is None:
            log.warning("no broker answered on %s; asking again", key)
            return None
        if answer.payload is None:
            log.warning("the broker refused a lease request: %s", answer.error)
            return None
        try:
            return decode(LeaseReply, answer.payload)
        except BadMessage as error:
            log.warning("ignored a bad lease reply: %s", error)
            return None


def _shown(text: str, limit: int = 200) -> str:
    """`text` fit for one line of a reply or a log: whatever a querier sent, bounded."""
    text = " ".join(text.split())
    return text if len(text) <= limit else f"{text[: limit - 3]}..."


def _no_ones_fault(reason: str) -> bool:
    """Whether the broker refused a result for a reason that is no one's fault, said quietly: a
    study that ended while its job ran (its analytic process stopped, or was stopped with
    Ctrl-C), or a copy of an overdue job whose other copy was taken first (the broker gives idle
    workers copies of stragglers: broker/queue.py), whether or not the study has collected that
    one yet. Those are the broker's reasons (broker/queue.py `complete`)."""
    return (
        reason.startswith("unknown study")
        or reason.endswith("is done already")
        or (reason.startswith("no job ") and "waits for a result" in reason)
    )
