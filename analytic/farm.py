"""The analytic side's door to the farm: submit candidates, get scored evaluations back. An
`Evaluator` (analytic.evaluator) whose jobs run on any number of cobots.

    with FarmClient(["tcp/127.0.0.1:7447"], study="spiral-pop30", run_dir=Path("runs/a")) as farm:
        farm.submit({"g0-spiral": spec, ...})
        for evaluation in farm.results():
            ...  # in completion order, each scored from its MCAP log, kept in run_dir/episodes/

The client holds the study's liveliness token (the broker drops the study's queued jobs when it
goes), keeps a deadline per job and resubmits a job whose result has not come by then, counts each
job once however many results arrive for it, and scores every episode from its log.
"""

import logging
import queue
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import zenoh

from analytic.evaluator import Evaluation, EvaluationStatus, accept_log
from broker.status import BrokerUnavailable, query_status
from schemas import keys
from schemas.episode import EpisodeSpec
from schemas.mcap_episode import NotAnEpisodeLog
from schemas.security import TlsIdentity
from schemas.transport import open_session, token_held
from schemas.wire import (
    MAX_EPISODE_BYTES,
    BadMessage,
    BrokerStatus,
    Job,
    JobStatus,
    Result,
    Submission,
    SubmitReply,
    decode,
)

log = logging.getLogger("gainfarm.analytic")

DEFAULT_DEADLINE = 600.0  # s from (re)submission: a backstop; leases and liveliness act sooner
DEFAULT_ATTEMPTS = 3
SUBMIT_CHUNK = 100  # jobs per Submission: the broker parses each in one go, holding the GIL
ANSWER_SECONDS = 10.0  # how long the broker has to answer a submission or a status query
RECHECK_SECONDS = 1.0  # a resubmitted job the broker still had: ask again this soon


BROKER_BACK = b"\0broker-back"  # an inbox marker, never a real attachment (those are JSON)


class FarmUnavailable(ConnectionError):
    """No broker answered, or the study is already open elsewhere."""


@dataclass
class _Pending:
    spec: EpisodeSpec
    deadline: float
    attempts: int = 1


class FarmClient:
    def __init__(
        self,
        connect: Sequence[str],
        study: str,
        run_dir: Path,
        *,
        deadline: float = DEFAULT_DEADLINE,
        attempts: int = DEFAULT_ATTEMPTS,
        identity: TlsIdentity | None = None,
    ):
        Submission(study=study, jobs=[])  # validates the name before it becomes a key
        self.study = study
        self.log_dir = Path(run_dir) / "episodes"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.deadline = deadline
        self.attempts = attempts
        self.duplicates = 0
        self.ignored = 0
        self._pending: dict[str, _Pending] = {}
        self._ready: list[Evaluation] = []
        self._inbox: queue.SimpleQueue[tuple[bytes | None, bytes]] = queue.SimpleQueue()
        self.session = open_session("client", connect=connect, identity=identity)
        try:
            self._open_study(connect)
        except BaseException:
            self.session.close()
            raise

    def __enter__(self) -> "FarmClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if not self.session.is_closed():
            self.session.close()  # undeclares the token: the broker drops what is still queued

    @property
    def pending(self) -> int:
        """Jobs submitted whose evaluation has not been handed out yet."""
        return len(self._pending) + len(self._ready)

    def status(self) -> BrokerStatus:
        return query_status(self.session)

    @property
    def capacity(self) -> int:
        """The workers connected to the farm now: how many jobs can run at once."""
        return len(self.status().workers)

    def submit(self, specs: Mapping[str, EpisodeSpec]) -> None:
        """Queue one job per (job id, spec). A job id may not be pending already."""
        clash = sorted(set(specs) & set(self._pending))
        if clash:
            raise ValueError(f"job ids already pending: {', '.join(clash[:5])}")
        jobs = [Job(job_id=job_id, spec=spec) for job_id, spec in specs.items()]
        expiry = time.monotonic() + self.deadline
        for job in jobs:
            self._pending[job.job_id] = _Pending(job.spec, expiry)
        self._send(jobs)

    def cancel(self, job_ids: Iterable[str]) -> None:
        """Stop waiting for these jobs; a result that still comes for one is counted as a
        duplicate and dropped. (The broker may still run them: the study's token decides.)"""
        dropped = set(job_ids)
        for job_id in dropped:
            self._pending.pop(job_id, None)
        self._ready = [evaluation for evaluation in self._ready if evaluation.job_id not in dropped]

    def results(self, timeout: float | None = None) -> Iterator[Evaluation]:
        """Yield evaluations as they complete, until none is pending (or `timeout` s pass)."""
        give_up = None if timeout is None else time.monotonic() + timeout
        while self._pending or self._ready:
            while self._ready:
                yield self._ready.pop(0)
            if not self._pending:
                break
            now = time.monotonic()
            if give_up is not None and now >= give_up:
                return
            wake = min(pending.deadline for pending in self._pending.values())
            if give_up is not None:
                wake = min(wake, give_up)
            try:
                attachment, content = self._inbox.get(timeout=max(wake - now, 0.0))
            except queue.Empty:
                self._chase_overdue()
                continue
            if attachment is BROKER_BACK:
                self._rejoin()
                continue
            evaluation = self._receive(attachment, content)
            if evaluation is not None:
                yield evaluation

    # --- inside ----------------------------------------------------------------------------

    def _open_study(self, connect: Sequence[str]) -> None:
        token_key = keys.alive_study(self.study)
        if token_held(self.session, token_key):
            raise FarmUnavailable(f"study {self.study!r} is already open in another process")
        self._subscriber = self.session.declare_subscriber(
            keys.study_results(self.study), self._on_result
        )
        self._token = self.session.liveliness().declare_token(token_key)
        self._broker_watch = self.session.liveliness().declare_subscriber(
            keys.ALIVE_BROKER, self._on_broker_token
        )
        self._await_study(", ".join(connect))

    def _await_study(self, where: str) -> None:
        """The broker learns of the study from the token; wait until it has, so that a
        submission cannot overtake it."""
        give_up = time.monotonic() + ANSWER_SECONDS
        while time.monotonic() < give_up:
            try:
                status = query_status(self.session, timeout=1.0)
            except BrokerUnavailable:
                time.sleep(0.1)
                continue
            if any(study.name == self.study for study in status.studies):
                return
            time.sleep(0.02)
        raise FarmUnavailable(f"no gainfarm broker answered at {where}")

    def _on_broker_token(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:  # a broker (re)started, with an empty queue
            self._inbox.put((BROKER_BACK, b""))

    def _rejoin(self) -> None:
        """A new broker knows none of our jobs: once it knows the study, submit them all again.
        Its restart lost them, the worker did not fail them: no attempt is counted."""
        log.warning("a broker (re)started; resubmitting %d pending jobs", len(self._pending))
        self._await_study("the restarted broker")
        now = time.monotonic()
        for pending in self._pending.values():
            pending.deadline = now + self.deadline
        self._send([Job(job_id=job_id, spec=p.spec) for job_id, p in self._pending.items()])

    def _on_result(self, sample: zenoh.Sample) -> None:
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
        self._inbox.put((attachment, sample.payload.to_bytes()))

    def _send(self, jobs: list[Job]) -> set[str]:
        """Submit `jobs`; return the ids the broker still had queued or running."""
        still_pending: set[str] = set()
        for start in range(0, len(jobs), SUBMIT_CHUNK):
            chunk = jobs[start : start + SUBMIT_CHUNK]
            reply = self._ask(Submission(study=self.study, jobs=chunk))
            if reply is None:  # the deadline will resubmit them
                log.warning("the broker did not answer a submission of %d jobs", len(chunk))
                continue
            still_pending.update(reply.already_pending)
            for rejection in reply.rejected:
                pending = self._pending.pop(rejection.job_id, None)
                if pending is not None:
                    self._ready.append(self._failed(rejection.job_id, pending, rejection.reason))
        return still_pending

    def _ask(self, submission: Submission) -> SubmitReply | None:
        for reply in self.session.get(
            keys.SUBMIT, payload=submission.to_bytes(), timeout=ANSWER_SECONDS
        ):
            if reply.ok is None:
                reason = reply.err.payload.to_bytes().decode(errors="replace")
                raise BadMessage(f"the broker refused a submission: {reason}")
            return decode(SubmitReply, reply.ok.payload.to_bytes())
        return None

    def _chase_overdue(self) -> None:
        """Resubmit every job past its deadline; give up on those out of attempts."""
        now = time.monotonic()
        overdue = [job_id for job_id, pending in self._pending.items() if pending.deadline <= now]
        again = []
        for job_id in overdue:
            pending = self._pending[job_id]
            if pending.attempts >= self.attempts:
                del self._pending[job_id]
                reason = f"no result after {pending.attempts} attempts"
                self._ready.append(self._failed(job_id, pending, reason, EvaluationStatus.lost))
                continue
            pending.attempts += 1
            pending.deadline = now + self.deadline
            again.append(Job(job_id=job_id, spec=pending.spec))
        if again:
            log.warning("resubmitting %d overdue jobs", len(again))
            for job_id in self._send(again):  # merely slow, not lost: not another attempt
                if job_id in self._pending:
                    self._pending[job_id].attempts -= 1

    def _receive(self, attachment: bytes | None, content: bytes) -> Evaluation | None:
        try:
            result = decode(Result, attachment)
        except BadMessage as error:
            self.ignored += 1
            log.warning("ignored a result: %s", error)
            return None
        if result.study != self.study:
            self.ignored += 1
            log.warning("ignored a result of study %r on this study's key", result.study)
            return None
        pending = self._pending.get(result.job_id)
        if pending is None:  # already evaluated (or never submitted here): counted once
            self.duplicates += 1
            return None
        common = dict(
            job_id=result.job_id,
            spec=pending.spec,
            worker=result.worker,
            attempts=pending.attempts,
            timings=result.timings,
        )
        if result.status == JobStatus.failed:
            del self._pending[result.job_id]
            return Evaluation(
                **common,
                status=EvaluationStatus.failed,
                scores=None,
                log=None,
                reason=result.reason,
            )
        path = self.log_dir / f"{result.job_id}.mcap"
        try:
            if len(content) > MAX_EPISODE_BYTES or len(content) != result.episode_bytes:
                raise NotAnEpisodeLog(f"{len(content)} bytes, not the {result.episode_bytes} sent")
            source = f"episode of {result.job_id} from {result.worker}"
            scores = accept_log(content, pending.spec, path, source)
        except NotAnEpisodeLog as error:
            return self._run_again(result, pending, f"unusable episode log: {error}")
        del self._pending[result.job_id]
        return Evaluation(
            **common,
            status=EvaluationStatus(result.status.value),
            scores=scores,
            log=path,
            reason=result.reason,
        )

    def _run_again(self, result: Result, pending: _Pending, reason: str) -> Evaluation | None:
        """A log damaged on its way is a lost result, not the job's outcome: the episode is
        deterministic, so run it again (an attempt) rather than score nothing."""
        log.warning("job %s from %s: %s", result.job_id, result.worker, reason)
        if pending.attempts >= self.attempts:
            del self._pending[result.job_id]
            return self._failed(result.job_id, pending, f"{reason} (attempt {pending.attempts})")
        pending.attempts += 1
        # The broker may not have closed the damaged lease yet and answer "already pending":
        # look again soon rather than after a whole deadline.
        still_pending = self._send([Job(job_id=result.job_id, spec=pending.spec)])
        wait = RECHECK_SECONDS if result.job_id in still_pending else self.deadline
        pending.deadline = time.monotonic() + wait
        return None

    def _failed(
        self,
        job_id: str,
        pending: _Pending,
        reason: str,
        status: EvaluationStatus = EvaluationStatus.failed,
    ) -> Evaluation:
        return Evaluation(
            job_id=job_id,
            spec=pending.spec,
            status=status,
            scores=None,
            log=None,
            reason=reason,
            worker="",
            attempts=pending.attempts,
            timings=None,
        )
