"""The broker on the wire: a Zenoh router in this process, and the LeaseQueue behind four
queryables (submit, lease, confirm, status) and two liveliness subscribers.

Everything Zenoh stays here; every scheduling decision is the queue's. Zenoh calls back on its
own threads, so one lock guards the queue, and replies go out after it is released. Episode logs
(fetched in parts) never pass through the broker's code: a worker hands in the Results of a batch
of leases with its next lease request, then sends each taken one to its study; the study asks the
broker which results it took.
"""

import functools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence

import zenoh

from gainfarm.broker.queue import (
    DEFAULT_MAX_QUEUED,
    DEFAULT_MAX_QUEUED_PER_STUDY,
    Assignment,
    LeaseQueue,
    UnknownStudy,
)
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session
from gainfarm.schemas import keys
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.wire import (
    LEASE_HOLD_SECONDS,
    MAX_MESSAGE_BYTES,
    BadMessage,
    BrokerStatus,
    ConfirmReply,
    ConfirmRequest,
    LeaseReply,
    LeaseRequest,
    Rejection,
    SubmitReply,
    Verdict,
    WireMessage,
    decode,
    decode_submission,
)

log = logging.getLogger("gainfarm.broker")

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
TICK_SECONDS = 0.05  # how often held requests and leases are checked for expiry


def _guarded(handler: Callable[["Broker", zenoh.Query], None]) -> Callable:
    """Whatever a query does to a handler, it gets an answer and the broker serves on."""

    @functools.wraps(handler)
    def serve(self: "Broker", query: zenoh.Query) -> None:
        try:
            handler(self, query)
        except BadMessage as error:
            self._reject_query(query, str(error))
        except Exception:  # a bug, not the sender's fault: say so, and keep serving
            log.exception("failed to answer a query on %s", query.key_expr)
            self._reject_query(query, "the broker failed to answer (see its log)")

    return serve


class Broker:
    """Run with `with Broker([...]) as broker:`; it serves from its own threads until closed."""

    def __init__(
        self,
        listen: Sequence[str] = (DEFAULT_LISTEN,),
        lease_seconds: float = 60.0,
        hold_seconds: float = LEASE_HOLD_SECONDS,
        identity: TlsIdentity | None = None,
        *,
        max_queued: int = DEFAULT_MAX_QUEUED,
        max_queued_per_study: int = DEFAULT_MAX_QUEUED_PER_STUDY,
        submit_rate: float | None = None,
    ):
        """With `identity` (the broker's TLS credentials) the router runs the secure profile:
        TLS with mutual authentication, and the access policy of schemas/security.py. The
        queue caps and the submission rate (jobs/s per study) bound what studies can queue."""
        self.endpoints = list(listen)
        self.queue: LeaseQueue[zenoh.Query] = LeaseQueue(
            lease_seconds,
            max_queued=max_queued,
            max_queued_per_study=max_queued_per_study,
            submit_rate=submit_rate,
        )
        self.hold_seconds = hold_seconds
        self.rejected = 0
        self._lock = threading.Lock()
        self._held: deque[tuple[float, str, zenoh.Query]] = deque()  # by deadline: hold is fixed
        self._closed = threading.Event()
        # The router forwards episode logs and models too, but in parts (schemas.parts): it takes
        # no message larger than a wire message, and drops a larger one unassembled.
        self.session = open_session(
            "router", listen=listen, identity=identity, max_message_bytes=SERVING_SESSION_BYTES
        )
        liveliness = self.session.liveliness()
        self._entities = [
            liveliness.declare_subscriber(keys.ALIVE_STUDIES, self._on_study_token, history=True),
            liveliness.declare_subscriber(keys.ALIVE_WORKERS, self._on_worker_token, history=True),
            self.session.declare_queryable(keys.SUBMIT_ANY, self._on_submit),
            self.session.declare_queryable(keys.LEASE_ANY, self._on_lease_request),
            self.session.declare_queryable(keys.CONFIRM_ANY, self._on_confirm),
            self.session.declare_queryable(keys.STATUS, self._on_status),
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
                worker_count=self.queue.worker_count(),
                busy=self.queue.busy(),
                study_count=self.queue.study_count(),
                queued=self.queue.queued(),
            )

    # --- queryables ------------------------------------------------------------------------

    @_guarded
    def _on_submit(self, query: zenoh.Query) -> None:
        study, jobs, rejected = decode_submission(_payload(query))
        _check_named(query, study, "study")
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
            deferred=outcome.deferred if outcome else [],
            rejected=rejected,
        )
        for rejection in rejected[:10]:  # a flood of bad jobs must not flood the log
            log.warning("rejected job %s/%s: %s", study, rejection.job_id, rejection.reason)
        if reply.deferred:
            log.warning("study %s: %d jobs deferred (queue full)", study, len(reply.deferred))
        _answer(query, reply)
        if outcome:
            self._deliver(outcome.assignments)

    @_guarded
    def _on_lease_request(self, query: zenoh.Query) -> None:
        """A worker hands in its last batch's results and asks for more work. A result is taken
        only from the lease holder; a request that hands results in is answered at once (its
        worker sends them on only once it knows the verdicts), one that does not is held."""
        request = decode(LeaseRequest, _payload(query))
        _check_named(query, request.worker, "worker")
        verdicts = []
        with self._lock:
            for result in request.results:
                refusal = self.queue.complete(
                    result.study,
                    result.job_id,
                    result.lease_id,
                    result.worker,
                    result.digest,
                    result.scores,
                )
                if refusal is not None:
                    self.rejected += 1
                    log.info("result for %s/%s refused: %s", result.study, result.job_id, refusal)
                verdicts.append(
                    Verdict(
                        job_id=result.job_id,
                        lease_id=result.lease_id,
                        accepted=refusal is None,
                        reason=refusal or "",
                    )
                )
            wait = not request.results
            abandoned = self.queue.abandoned
            leases, replaced = self.queue.request(request.worker, query, request.want, wait)
            abandoned = self.queue.abandoned - abandoned
            if not leases and wait and request.want > 0:
                self._held.append((time.monotonic() + self.hold_seconds, request.worker, query))
        if abandoned:  # a hoarder, or an answer with leases lost on its way
            log.warning(
                "worker %s asked again without handing in %d leases: their jobs are queued "
                "again, and it gets none for a while",
                request.worker,
                abandoned,
            )
        if replaced is not None:
            _answer(replaced, LeaseReply())
        if leases or not wait or request.want == 0:
            _answer(query, LeaseReply(leases=leases, verdicts=verdicts))

    @_guarded
    def _on_confirm(self, query: zenoh.Query) -> None:
        request = decode(ConfirmRequest, _payload(query))
        _check_named(query, request.study, "study")
        with self._lock:
            accepted = self.queue.confirm(request.study, request.job_ids)
        _answer(query, ConfirmReply(study=request.study, accepted=accepted))

    @_guarded
    def _on_status(self, query: zenoh.Query) -> None:
        _answer(query, self.status())

    # --- subscribers -----------------------------------------------------------------------

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
            _answer(assignment.waiter, LeaseReply(leases=assignment.leases))

    def _reject_query(self, query: zenoh.Query, reason: str) -> None:
        with self._lock:
            self.rejected += 1
        log.warning("rejected a query on %s: %s", query.key_expr, reason)
        try:
            query.reply_err(reason.encode())
        except zenoh.ZError as error:
            log.warning("could not answer a query: %s", error)
        finally:
            query.drop()


def _payload(query: zenoh.Query) -> bytes | None:
    """The query's bytes, refused by their size before they are copied out of Zenoh."""
    if query.payload is None:
        return None
    size = len(query.payload)
    if size > MAX_MESSAGE_BYTES:
        raise BadMessage(f"{size} bytes, over the limit of {MAX_MESSAGE_BYTES}: not read")
    return query.payload.to_bytes()


def _check_named(query: zenoh.Query, name: str, what: str) -> None:
    """A service's key names whom the query acts for (the access policy checks the key): the
    message must name the same."""
    chunk = keys.last_chunk(str(query.key_expr))
    if chunk != name:
        raise BadMessage(f"the message's {what} {name!r} is not the key's {chunk!r}")


def _answer(query: zenoh.Query, reply: WireMessage) -> None:
    """Reply and let go; a client that vanished meanwhile is the liveliness token's business."""
    try:
        query.reply(query.key_expr, reply.to_bytes())
    except zenoh.ZError as error:
        log.warning("could not answer a query on %s: %s", query.key_expr, error)
    finally:
        query.drop()
