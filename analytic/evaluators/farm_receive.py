"""Results taken in on the client's thread: each arrival held until the broker confirms it is the
one it took (the broker's record stands in for one that never came: a silent holder's, or one
lost or dropped on the way), then checked: a stranger's refused, a worker's refusal (it lacks a
plug-in) sent elsewhere, a failure taken as it is, and a kept log fetched from its worker, whose
bytes and scores must be what was claimed; what passes is ready to hand out."""

import logging
import time
from collections.abc import Iterator, Mapping
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import (
    EpisodeResult,
    EpisodeStatus,
    ReadLog,
    Wanted,
)
from gainfarm.analytic.evaluators.farm_inbox import Arrival, Inbox, matches
from gainfarm.analytic.evaluators.farm_jobs import (
    RECHECK_SECONDS,
    SILENT_BATCH,
    SILENT_FRACTION,
    Jobs,
    Pending,
)
from gainfarm.analytic.evaluators.farm_link import ANSWER_SECONDS
from gainfarm.analytic.evaluators.farm_logs import FETCHES_AT_ONCE, Logs
from gainfarm.analytic.evaluators.farm_workers import Workers, lacked_here
from gainfarm.edges.ask import ask
from gainfarm.plugins import PluginError
from gainfarm.schemas import keys
from gainfarm.schemas.episode import Scores
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog
from gainfarm.schemas.wire import (
    MAX_EPISODE_BYTES,
    Accepted,
    BadMessage,
    ConfirmReply,
    ConfirmRequest,
    JobStatus,
    Result,
    decode,
)

log = logging.getLogger("gainfarm.analytic")

CONFIRM_BATCH = 1000  # results confirmed in one question to the broker
# How long the result the broker took for a job may take to reach us after the broker said so
# (a worker hands its result in, then puts it); then the broker's record stands in for it, or
# the job runs again.
TAKEN_PATIENCE = 1.0  # s


class Receiver:
    """A study's results, from their arrival to the evaluation ready in `jobs`."""

    def __init__(
        self,
        jobs: Jobs,
        inbox: Inbox,
        workers: Workers,
        logs: Logs,
        log_dir: Path,
        read_log: ReadLog,
    ):
        self.jobs = jobs
        self.inbox = inbox
        self.workers = workers
        self.logs = logs
        self.log_dir = log_dir
        self.read_log = read_log
        self.arrived: dict[str, list[Arrival]] = {}  # by job id, until the broker confirms

    def forget(self, job_id: str) -> None:
        """Stop waiting for a cancelled job's results."""
        self.inbox.release(self.arrived.pop(job_id, []))
        self.inbox.forget(job_id)

    def ask_about(self, job_ids: set[str]) -> None:
        """Ask the broker which result it took for these jobs (one was dropped here)."""
        for job_id in job_ids & self.jobs.pending.keys():
            self.arrived.setdefault(job_id, [])  # the broker tells which result it took

    def arrive(self, arrival: Arrival) -> None:
        """Keep a result as it arrives for the broker to confirm; or take it, if it is the one
        the broker already said it took."""
        job_id = arrival.result.job_id
        if job_id not in self.jobs.pending:  # evaluated or cancelled since it came
            self.inbox.release([arrival])
            self.inbox.duplicate()
            return
        taken = arrival.taken
        if taken is None:  # the broker may have said so while it waited in the inbox
            taken = self.inbox.claim(arrival.result)
        if taken is None:
            self.arrived.setdefault(job_id, []).append(arrival)
            return
        self.inbox.release([arrival])
        result = self.receive(arrival)
        if result is not None:
            self.jobs.ready.append(result)

    def confirm(self) -> None:
        """Ask the broker which of the arrived results it took; each job's confirmed one is
        its evaluation, and every other is ignored. Unanswered: they wait for the next ask."""
        if not self.arrived:
            return
        job_ids = list(self.arrived)[:CONFIRM_BATCH]
        reply = self._confirmed(job_ids, "the broker did not confirm results")
        if reply is None:
            return
        taken = {accepted.job_id: accepted for accepted in reply.accepted}
        now = time.monotonic()
        received: list[Arrival] = []  # confirmed: evaluated below, their logs fetched in batches
        for job_id in job_ids:
            arrivals = self.arrived.pop(job_id)
            self.inbox.release(arrivals)
            accepted = taken.get(job_id)
            confirmed = [a for a in arrivals if accepted and matches(a.result, accepted)]
            others = len(arrivals) - min(len(confirmed), 1)
            if others:
                self.inbox.not_taken(others, job_id)
            if accepted is not None and not confirmed and job_id in self.jobs.pending:
                # The broker forgets what it has told: remember it until that result comes.
                self.inbox.remember([accepted], now)
            if confirmed and job_id in self.jobs.pending:
                received.append(confirmed[0])
        for batch in self._fetch_batches(received):
            logs = self.logs.fetch_at_once(
                {
                    arrival.result.job_id: (
                        Wanted(
                            self.jobs.pending[arrival.result.job_id].spec,
                            arrival.result.digest,
                            (arrival.result.worker,),
                        ),
                        arrival.result.episode_bytes,
                    )
                    for arrival in batch
                    if self._wants_log(arrival.result)
                }
            )
            for arrival in batch:
                if arrival.result.job_id in self.jobs.pending:
                    result = self.receive(arrival, logs)
                    if result is not None:
                        self.jobs.ready.append(result)

    def _confirmed(self, job_ids: list[str], unanswered: str) -> ConfirmReply | None:
        """The broker's word on which results it took for `job_ids`; None if it did not answer
        (the client waits for it, saying `unanswered`) or answered badly."""
        request = ConfirmRequest(study=self.jobs.link.study, job_ids=job_ids)
        answer = ask(
            self.jobs.link.session,
            keys.confirm(self.jobs.link.study),
            request.to_bytes(),
            ANSWER_SECONDS,
        )
        if answer is None:
            self.jobs.wait_for_broker(unanswered)
            return None
        try:
            if answer.payload is None:
                raise BadMessage(f"the broker refused to confirm results: {answer.error}")
            return decode(ConfirmReply, answer.payload)
        except BadMessage as error:
            log.warning("%s", error)
            return None

    # --- results that never came ---------------------------------------------------------------

    def ask_unheard(self) -> None:
        """Ask the broker about jobs whose results have not come in a while (those asked about
        longest ago first, SILENT_BATCH at most). A result it took for one is waited for
        TAKEN_PATIENCE more, in case it is on its way here (`chase_taken`)."""
        if self.jobs.link.waiting is not None:  # the broker is not answering: chase_overdue asks
            return
        now = time.monotonic()
        told = self.inbox.told()
        due = [
            (pending.ask_at, job_id)
            for job_id, pending in self.jobs.pending.items()
            if pending.ask_at <= now and job_id not in self.arrived and job_id not in told
        ]
        if not due:
            return
        job_ids = [job_id for _, job_id in sorted(due)[:SILENT_BATCH]]
        for job_id in job_ids:
            pending = self.jobs.pending[job_id]
            age = now - pending.submitted
            pending.ask_at = now + max(RECHECK_SECONDS, SILENT_FRACTION * age)
        reply = self._confirmed(job_ids, "the broker did not answer about unheard results")
        if reply is None:
            return
        asked = set(job_ids)
        # The broker forgets what it has told: remember it until it comes.
        self.inbox.remember([one for one in reply.accepted if one.job_id in asked], now)

    def chase_taken(self) -> None:
        """A result the broker took that has not come within TAKEN_PATIENCE of its saying so
        (withheld by a silent holder, lost on the way, or dropped here with max_held_bytes
        full): the broker's record stands in for it (`_from_record`)."""
        for accepted in self.inbox.overdue(TAKEN_PATIENCE):
            if accepted.job_id in self.jobs.pending:
                result = self._from_record(accepted)
                if result is not None:
                    self.jobs.ready.append(result)

    def _from_record(self, accepted: Accepted) -> EpisodeResult | None:
        """The evaluation of a job whose result the broker took but which never came here: the
        scores as handed in, the log left with the worker. A job that wanted its log, or whose
        record has no scores, runs again elsewhere (None). Unless this client dropped the result
        itself (its budget was full: `max_held_bytes`), its worker is left out."""
        jobs = self.jobs
        pending = jobs.pending[accepted.job_id]
        if self.workers.stranger(accepted.worker):
            return self._turn_away(accepted.job_id, accepted.worker, pending)
        blamed = not pending.dropped_here
        if blamed:
            self.inbox.unheard += 1
            self.workers.leave_out(accepted.worker)
        if accepted.scores is None or pending.keep_log:
            if not blamed:  # dropped here: run again, no attempt spent
                log.warning(
                    "job %s: its result was dropped here; running it again", accepted.job_id
                )
                pending.dropped_here = False
                pending.deadline = time.monotonic() + jobs.deadline
                jobs.send([jobs.job(accepted.job_id)])
                return None
            pending.avoid = tuple(sorted({*pending.avoid, accepted.worker}))
            what = "its log" if accepted.scores is not None else "why it did not run"
            reason = f"its result never came, and the broker's record lacks {what}"
            return jobs.run_again(accepted.job_id, accepted.worker, pending, reason)
        if blamed:
            log.warning(
                "job %s: %s handed its result in but never sent it; taken from the broker's record",
                accepted.job_id,
                accepted.worker,
            )
        del jobs.pending[accepted.job_id]
        scores = Scores.model_validate(accepted.scores.model_dump())
        return EpisodeResult(
            job_id=accepted.job_id,
            spec=pending.spec,
            status=EpisodeStatus.diverged if scores.diverged else EpisodeStatus.ok,
            scores=scores,
            log=None,
            reason="",
            worker=accepted.worker,
            attempts=pending.attempts,
            timings=None,
            digest=accepted.digest,
        )

    # --- a confirmed result, checked ----------------------------------------------------------

    def _wants_log(self, result: Result) -> bool:
        """Whether a confirmed result's log is to be fetched with it (`keep_log`, it ran)."""
        pending = self.jobs.pending.get(result.job_id)
        return (
            pending is not None
            and pending.keep_log
            and result.scores is not None
            and not self.workers.stranger(result.worker)
        )

    def _fetch_batches(self, arrivals: list[Arrival]) -> Iterator[list[Arrival]]:
        """`arrivals` in turn, in batches whose logs are fetched at once: FETCHES_AT_ONCE at
        most, and logs that say they add up to MAX_EPISODE_BYTES at most (one largest log), so
        what is held stays as before the logs came in parts."""
        batch: list[Arrival] = []
        claimed = 0
        for arrival in arrivals:
            size = arrival.result.episode_bytes if self._wants_log(arrival.result) else 0
            if batch and (len(batch) == FETCHES_AT_ONCE or claimed + size > MAX_EPISODE_BYTES):
                yield batch
                batch, claimed = [], 0
            batch.append(arrival)
            claimed += size
        if batch:
            yield batch

    def receive(
        self, arrival: Arrival, fetched: Mapping[str, bytes | None] | None = None
    ) -> EpisodeResult | None:
        """The evaluation a confirmed result makes; with `keep_log`, its log from its worker, in
        `fetched` (by job id: the log, or None if it could not be had) or fetched here (None if
        it cannot be had or is unusable: it runs again)."""
        jobs = self.jobs
        result = arrival.result
        pending = jobs.pending[result.job_id]
        common = dict(
            job_id=result.job_id,
            spec=pending.spec,
            worker=result.worker,
            attempts=pending.attempts,
            timings=result.timings,
            reason=result.reason,
        )
        if self.workers.stranger(result.worker):
            return self._turn_away(result.job_id, result.worker, pending)
        if result.status == JobStatus.refused:  # the worker lacks a plug-in
            return self._refused(result, pending)
        if result.status == JobStatus.failed:
            del jobs.pending[result.job_id]
            return EpisodeResult(
                **common,
                status=EpisodeStatus.failed,
                scores=None,
                log=None,
            )
        assert result.scores is not None  # the wire's rule for a job that ran
        claimed = Scores.model_validate(result.scores.model_dump())
        ran = dict(common, status=EpisodeStatus(result.status.value), digest=result.digest)
        if not pending.keep_log:  # its worker keeps the log: `fetch` brings it if wanted
            del jobs.pending[result.job_id]
            return EpisodeResult(**ran, scores=claimed, log=None)
        path = self.log_dir / f"{result.job_id}.mcap"
        if fetched is not None and result.job_id in fetched:
            content = fetched[result.job_id]
        else:
            want = Wanted(pending.spec, result.digest, (result.worker,))
            content, _ = self.logs.fetch_log(want, result.episode_bytes)
        if content is None:  # gone already (its store was full), or not served as the rules say
            reason = f"its log could not be fetched from {result.worker}"
            return jobs.run_again(result.job_id, result.worker, pending, reason)
        try:
            if len(content) != result.episode_bytes:
                raise NotAnEpisodeLog(f"{len(content)} bytes, not the {result.episode_bytes} sent")
            source = f"episode of {result.job_id} from {result.worker}"
            scores = self.read_log(content, pending.spec, path, source)
        except NotAnEpisodeLog as error:
            reason = f"unusable episode log: {error}"
            return jobs.run_again(result.job_id, result.worker, pending, reason)
        if scores != claimed:  # an honest log, false scores: the worker is not to be trusted
            path.unlink(missing_ok=True)
            self.workers.distrusted.add(result.worker)
            reason = f"its scores are not its log's ({result.worker} is distrusted)"
            return jobs.run_again(result.job_id, result.worker, pending, reason)
        del jobs.pending[result.job_id]
        return EpisodeResult(**ran, scores=scores, log=path)

    def _turn_away(self, job_id: str, worker: str, pending: Pending) -> None:
        """Refuse a result from a worker this client's local farm did not start (said once per
        worker): the job runs again on the farm's own, no attempt spent (a stranger cannot use
        them up), and the stranger gets none of the study's jobs."""
        self.workers.turn_away(worker)
        pending.avoid = tuple(sorted({*pending.avoid, worker}))
        self.jobs.resend(job_id, pending)

    def _refused(self, result: Result, pending: Pending) -> None:
        """A worker refused the job, lacking a plug-in it needs: not the job's outcome while
        another worker may run it. PluginError, naming the worker and the plug-in, if this
        process lacks it too, or no worker connected that has not refused it is left."""
        reason = f"worker {result.worker} refused job {result.job_id}: {result.reason}"
        self.workers.refused(pending.spec, result.worker)
        pending.avoid = tuple(sorted({*pending.avoid, result.worker}))
        if lacked_here(pending.spec) or not self.workers.others_for(pending.spec, pending.avoid):
            raise PluginError(reason)
        log.warning("%s; running it on another worker", reason)
        self.jobs.resend(result.job_id, pending)
