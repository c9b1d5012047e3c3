"""The broker on the wire: a Zenoh router in this process, and the LeaseQueue behind three
queryables, one result subscriber and two liveliness subscribers.

Everything Zenoh stays here; every scheduling decision is the queue's. Zenoh calls back on its
own threads, so one lock guards the queue, and replies go out after it is released.
"""

import logging
import threading
import time
from collections import deque
from collections.abc import Sequence

import zenoh

from broker.queue import Assignment, LeaseQueue, UnknownStudy
from schemas import keys
from schemas.security import TlsIdentity
from schemas.transport import open_session
from schemas.wire import (
    LEASE_HOLD_SECONDS,
    BadMessage,
    BrokerStatus,
    LeaseReply,
    LeaseRequest,
    Rejection,
    Result,
    SubmitReply,
    decode,
    decode_submission,
)

log = logging.getLogger("gainfarm.broker")

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
TICK_SECONDS = 0.05  # how often held requests and leases are checked for expiry


class Broker:
    """Run with `with Broker([...]) as broker:`; it serves from its own threads until closed."""

    def __init__(
        self,
        listen: Sequence[str] = (DEFAULT_LISTEN,),
        lease_seconds: float = 60.0,
        hold_seconds: float = LEASE_HOLD_SECONDS,
        identity: TlsIdentity | None = None,
    ):
        """With `identity` (the broker's TLS credentials) the router runs the secure profile:
        TLS with mutual authentication, and the access policy of schemas/security.py."""
        self.endpoints = list(listen)
        self.queue: LeaseQueue[zenoh.Query] = LeaseQueue(lease_seconds)
        self.hold_seconds = hold_seconds
        self.rejected = 0
        self._lock = threading.Lock()
        self._held: deque[tuple[float, str, zenoh.Query]] = deque()  # by deadline: hold is fixed
        self._closed = threading.Event()
        self.session = open_session("router", listen=listen, identity=identity)
        liveliness = self.session.liveliness()
        self._entities = [
            liveliness.declare_subscriber(keys.ALIVE_STUDIES, self._on_study_token, history=True),
            liveliness.declare_subscriber(keys.ALIVE_WORKERS, self._on_worker_token, history=True),
            self.session.declare_queryable(keys.SUBMIT, self._on_submit),
            self.session.declare_queryable(keys.LEASE, self._on_lease_request),
            self.session.declare_queryable(keys.STATUS, self._on_status),
            self.session.declare_subscriber(keys.ALL_RESULTS, self._on_result),
        ]
        # Last, once it can serve: clients that see it appear resubmit what they still wait for.
        self._entities.append(liveliness.declare_token(keys.ALIVE_BROKER))
        self._ticker = threading.Thread(target=self._tick, name="broker-ticker", daemon=True)
        self._ticker.start()
        log.info("broker listening on %s", ", ".join(listen))

    def __enter__(self) -> "Broker":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._closed.is_set():
            return
        self._closed.set()
        self._ticker.join()
        for entity in self._entities:
            entity.undeclare()
        self.session.close()

    def status(self) -> BrokerStatus:
        with self._lock:
            return BrokerStatus(
                uptime_s=self.queue.uptime(),
                workers=self.queue.worker_states(),
                studies=self.queue.study_states(),
                jobs_done=self.queue.jobs_done,
                jobs_per_s=self.queue.jobs_per_second(),
                requeued=self.queue.requeued,
                rejected=self.rejected,
            )

    # --- queryables ------------------------------------------------------------------------

    def _on_submit(self, query: zenoh.Query) -> None:
        try:
            study, jobs, rejected = decode_submission(_payload(query))
        except BadMessage as error:
            self._reject_query(query, error)
            return
        with self._lock:
            try:
                outcome = self.queue.submit(study, jobs)
            except UnknownStudy:
                reason = f"unknown study {study!r}: no analytic process holds its liveliness token"
                rejected += [Rejection(job_id=job.job_id, reason=reason) for job in jobs]
                outcome = None
            self.rejected += len(rejected)
        reply = SubmitReply(
            study=study,
            queued=outcome.queued if outcome else [],
            already_pending=outcome.already_pending if outcome else [],
            rejected=rejected,
        )
        for rejection in rejected:
            log.warning("rejected job %s/%s: %s", study, rejection.job_id, rejection.reason)
        query.reply(keys.SUBMIT, reply.to_bytes())
        query.drop()
        if outcome:
            self._deliver(outcome.assignments)

    def _on_lease_request(self, query: zenoh.Query) -> None:
        try:
            request = decode(LeaseRequest, _payload(query))
        except BadMessage as error:
            self._reject_query(query, error)
            return
        with self._lock:
            lease, replaced = self.queue.request(request.worker, query)
            if lease is None:
                self._held.append((time.monotonic() + self.hold_seconds, request.worker, query))
        if replaced is not None:
            _answer(replaced, LeaseReply())
        if lease is not None:
            _answer(query, LeaseReply(lease=lease))

    def _on_status(self, query: zenoh.Query) -> None:
        query.reply(keys.STATUS, self.status().to_bytes())
        query.drop()

    # --- subscribers -----------------------------------------------------------------------

    def _on_result(self, sample: zenoh.Sample) -> None:
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
        try:
            result = decode(Result, attachment)
        except BadMessage as error:
            with self._lock:
                self.rejected += 1
            log.warning("ignored a result on %s: %s", sample.key_expr, error)
            return
        with self._lock:
            first = self.queue.complete(result.study, result.job_id, result.worker)
        if not first:
            log.info("duplicate result for %s/%s ignored", result.study, result.job_id)

    def _on_worker_token(self, sample: zenoh.Sample) -> None:
        name = keys.last_chunk(str(sample.key_expr))
        if sample.kind == zenoh.SampleKind.PUT:
            with self._lock:
                self.queue.worker_joined(name)
            log.info("worker %s joined", name)
            return
        with self._lock:
            assignments, orphan = self.queue.worker_lost(name)
        if orphan is not None:
            orphan.drop()
        log.info("worker %s left; its job, if any, is back in the queue", name)
        self._deliver(assignments)

    def _on_study_token(self, sample: zenoh.Sample) -> None:
        name = keys.last_chunk(str(sample.key_expr))
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.queue.open_study(name)
                dropped = None
            else:
                dropped = self.queue.close_study(name)
        if dropped is None:
            log.info("study %s opened", name)
        else:
            log.info("study %s closed; %d queued jobs dropped", name, dropped)

    # --- timers and replies ----------------------------------------------------------------

    def _tick(self) -> None:
        """Answer requests held too long with "no work", and take back expired leases."""
        while not self._closed.wait(TICK_SECONDS):
            now = time.monotonic()
            released = []
            with self._lock:
                while self._held and self._held[0][0] <= now:
                    _, worker, query = self._held.popleft()
                    if self.queue.withdraw(worker, query):
                        released.append(query)
                assignments = self.queue.expire()
            for query in released:
                _answer(query, LeaseReply())
            self._deliver(assignments)

    def _deliver(self, assignments: list[Assignment[zenoh.Query]]) -> None:
        for assignment in assignments:
            _answer(assignment.waiter, LeaseReply(lease=assignment.lease))

    def _reject_query(self, query: zenoh.Query, error: BadMessage) -> None:
        with self._lock:
            self.rejected += 1
        log.warning("rejected a query on %s: %s", query.key_expr, error)
        query.reply_err(str(error).encode())
        query.drop()


def _payload(query: zenoh.Query) -> bytes | None:
    return query.payload.to_bytes() if query.payload is not None else None


def _answer(query: zenoh.Query, reply: LeaseReply) -> None:
    """Reply and let go; a worker that vanished meanwhile is the liveliness token's business."""
    try:
        query.reply(keys.LEASE, reply.to_bytes())
    except zenoh.ZError as error:
        log.warning("could not answer a lease request: %s", error)
    finally:
        query.drop()
