"""A study's jobs while they are pending, and their submission: each job's spec, deadline,
attempts and the workers it avoids; submitted to the broker in chunks, submitted again when
overdue, deferred (the broker's queue is full), lost with a restarted broker, or handed back by a
worker; failed when out of attempts. Results ready to hand out wait here, in order."""

import logging
import time
from collections import deque
from collections.abc import Collection, Mapping
from dataclasses import dataclass

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus
from gainfarm.analytic.evaluators.farm_link import ANSWER_SECONDS, FarmUnavailable, StudyLink
from gainfarm.analytic.evaluators.farm_workers import Workers
from gainfarm.edges.ask import ask
from gainfarm.schemas import keys
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.wire import BadMessage, Job, Submission, SubmitReply, decode

log = logging.getLogger("gainfarm.analytic")

SUBMIT_CHUNK = 100  # jobs per Submission: the broker parses each in one go, holding the GIL
RECHECK_SECONDS = 1.0  # how often overdue jobs are looked for, and unconfirmed results asked about
# A job with no result this long after its submission is asked about (farm.py's doc), then again
# after SILENT_FRACTION of its age (at least RECHECK_SECONDS later): a result withheld costs
# about that fraction of the wait more, and a deep queue's jobs are not all asked about at once:
# at most SILENT_BATCH of them, those asked about longest ago first, once a RECHECK_SECONDS.
SILENT_AFTER = 2.0  # s
SILENT_FRACTION = 0.25
SILENT_BATCH = 200


@dataclass
class Pending:
    spec: EpisodeSpec
    deadline: float
    attempts: int = 1
    avoid: tuple[str, ...] = ()  # workers that may not run it
    keep_log: bool = True  # its log is fetched as soon as its result is confirmed
    submitted: float = 0.0  # monotonic time of its first submission
    ask_at: float = 0.0  # when to ask the broker about it if no result has come (SILENT_AFTER)
    dropped_here: bool = False  # a result of it was dropped here, max_held_bytes being full


class Jobs:
    """The pending jobs of the study `link` opened, by job id, and the results ready."""

    def __init__(self, link: StudyLink, workers: Workers, deadline: float, attempts: int):
        self.link = link
        self.workers = workers
        self.deadline = deadline
        self.attempts = attempts
        self.pending: dict[str, Pending] = {}
        self.ready: deque[EpisodeResult] = deque()

    def add(
        self, specs: Mapping[str, EpisodeSpec], avoid: Mapping[str, Collection[str]], keep: bool
    ) -> None:
        """Take these jobs in and submit them."""
        now = time.monotonic()
        for job_id, spec in specs.items():
            self.pending[job_id] = Pending(
                spec,
                now + self.deadline,
                avoid=tuple(avoid.get(job_id, ())),
                keep_log=keep,
                submitted=now,
                ask_at=now + SILENT_AFTER,
            )
        self.send([self.job(job_id) for job_id in specs])

    def job(self, job_id: str) -> Job:
        pending = self.pending[job_id]
        refusers = self.workers.refusers(pending.spec)
        avoid = sorted({*pending.avoid, *self.workers.barred(), *refusers})
        return Job(job_id=job_id, spec=pending.spec, avoid=avoid, keep_log=pending.keep_log)

    def send(self, jobs: list[Job]) -> set[str]:
        """Submit `jobs`; return the ids the broker did not newly queue: those it still had
        queued or running, those it deferred (its queue is full) and those it did not hear."""
        not_queued: set[str] = set()
        for start in range(0, len(jobs), SUBMIT_CHUNK):
            chunk = jobs[start : start + SUBMIT_CHUNK]
            reply = self._ask(Submission(study=self.link.study, jobs=chunk))
            if reply is None:  # the deadline will resubmit them, once the broker answers
                self.wait_for_broker("the broker did not answer a submission")
                not_queued.update(job.job_id for job in chunk)
                continue
            not_queued.update(reply.already_pending)
            not_queued.update(reply.deferred)
            if reply.deferred:  # a full queue is no verdict: submit them again soon
                log.warning("the broker deferred %d jobs: its queue is full", len(reply.deferred))
                soon = time.monotonic() + RECHECK_SECONDS
                for job_id in reply.deferred:
                    if job_id in self.pending:
                        self.pending[job_id].deadline = soon
            for rejection in reply.rejected:
                pending = self.pending.pop(rejection.job_id, None)
                if pending is not None:
                    self.ready.append(failed(rejection.job_id, pending, rejection.reason))
        return not_queued

    def _ask(self, submission: Submission) -> SubmitReply | None:
        answer = ask(
            self.link.session,
            keys.submit(self.link.study),
            submission.to_bytes(),
            timeout=ANSWER_SECONDS,
        )
        if answer is None:
            return None
        if answer.payload is None:
            raise BadMessage(f"the broker refused a submission: {answer.error}")
        return decode(SubmitReply, answer.payload)

    def wait_for_broker(self, why: str) -> None:
        """No answer from the broker is no verdict on any job: wait, saying so, and spend no
        attempts until it answers again."""
        self.link.wait(why, len(self.pending))
        later = time.monotonic() + self.deadline
        for pending in self.pending.values():
            pending.deadline = max(pending.deadline, later)

    def rejoin(self) -> None:
        """A new broker knows none of our jobs: once it knows the study, submit them all again.
        Its restart lost them, the worker did not fail them: no attempt is counted."""
        log.warning("a broker (re)started; resubmitting %d pending jobs", len(self.pending))
        self.link.back()
        try:
            self.link.await_study("the restarted broker")
        except FarmUnavailable as error:
            self.wait_for_broker(str(error))
            return
        now = time.monotonic()
        for pending in self.pending.values():
            pending.deadline = now + self.deadline
        self.send([self.job(job_id) for job_id in self.pending])

    def chase_overdue(self) -> None:
        """Resubmit every job past its deadline; give up on those out of attempts. Only while
        the broker answers: without it, no job's time runs out."""
        now = time.monotonic()
        overdue = [job_id for job_id, pending in self.pending.items() if pending.deadline <= now]
        if not overdue:
            return
        if not self.link.answers():
            self.wait_for_broker("no answer from the broker")
            return
        now = time.monotonic()
        again = []
        for job_id in overdue:
            pending = self.pending[job_id]
            if pending.attempts >= self.attempts:
                del self.pending[job_id]
                reason = f"no result after {pending.attempts} attempts"
                self.ready.append(failed(job_id, pending, reason, EpisodeStatus.lost))
                continue
            pending.attempts += 1
            pending.deadline = now + self.deadline
            again.append(self.job(job_id))
        if again:
            log.warning("resubmitting %d overdue jobs", len(again))
            for job_id in self.send(again):  # merely slow, not lost: not another attempt
                if job_id in self.pending:
                    self.pending[job_id].attempts -= 1

    def resend(self, job_id: str, pending: Pending) -> None:
        """Submit the job again, avoiding whom it now avoids. The broker may not have closed
        the lease yet and answer "already pending": look again soon, not after a deadline."""
        still_pending = self.send([self.job(job_id)])
        wait = RECHECK_SECONDS if job_id in still_pending else self.deadline
        pending.deadline = time.monotonic() + wait

    def run_again(
        self, job_id: str, worker: str, pending: Pending, reason: str
    ) -> EpisodeResult | None:
        """A log damaged on its way is a lost result, not the job's outcome: the episode is
        deterministic, so run it again (an attempt) rather than score nothing."""
        log.warning("job %s from %s: %s", job_id, worker, reason)
        if pending.attempts >= self.attempts:
            del self.pending[job_id]
            return failed(job_id, pending, f"{reason} (attempt {pending.attempts})")
        pending.attempts += 1
        self.resend(job_id, pending)
        return None


def failed(
    job_id: str,
    pending: Pending,
    reason: str,
    status: EpisodeStatus = EpisodeStatus.failed,
) -> EpisodeResult:
    return EpisodeResult(
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
