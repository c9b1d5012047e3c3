"""The analytic side's door to the farm: submit candidates, get scored evaluations back. An
`Evaluator` (analytic.evaluator) whose jobs run on any number of cobots.

    with FarmClient(["tcp/127.0.0.1:7447"], study="spiral-pop30", run_dir=Path("runs/a")) as farm:
        farm.submit({"g0-spiral": spec, ...})
        for evaluation in farm.results():
            ...  # in completion order, each scored from its MCAP log, kept in run_dir/episodes/

The client holds the study's liveliness token (the broker drops the study's queued jobs when it
goes), keeps a deadline per job and resubmits a job whose result has not come by then, and counts
each job once however many results arrive for it.

Every result brings the scores its worker computed from its log, never the log: the worker keeps
it, and serves it in parts (gainfarm/edges/parts.py). With `keep_logs` (the default) the client
fetches each confirmed result's log from its worker at once: it must be the digest's bytes and
score as claimed, and is kept. Without it the evaluation is the worker's scores, and `fetch`
brings the logs wanted later (checked by their digest and scored again here; a log gone is
simulated again).

A result counts only once the broker confirms it: the broker takes a result from the worker that
holds the job's lease alone, and tells the study which one it took (lease, worker, the log's
SHA-256 and the scores). Anyone else's result for the job, however well made, is ignored, and so
is any answer that does not come from the broker. A broker that does not answer costs no job an
attempt: the client waits for it, and says so (`waiting`).

A worker may hand a result in to the broker and never send it here (a silent holder, or one that
died in between). So a job whose result has not come SILENT_AFTER seconds after it was submitted
is asked about too, and again after a quarter of its age each time: when the broker took a result
for it, its record (worker, digest, scores as handed in) is the evaluation, its log left with its
worker (`fetch` brings it, or simulates it again); a job that wanted its log, or whose record has
no scores (failed, or refused: the record does not say which, nor why), runs again elsewhere. A
worker whose result never came gets none of the study's jobs from then on, while another worker
is there to run them (`unheard_from`).

Anyone on the farm may put samples on the study's keys. The client has one session, and it takes
no message larger than a wire message (SERVING_SESSION_BYTES): Zenoh drops a larger sample, or a
larger query on the model key, on the way instead of reassembling it, and logs and models move in
parts no larger. The client reads each sample's small attachment (the Result) on Zenoh's thread,
and holds it only for a result this study waits for, with no payload (a result carries no log),
and only while the results it holds unconfirmed stay within MAX_HELD_BYTES; everything else is
dropped and counted (`ignored`, `duplicates`, `unconfirmed`, `dropped`). A result the broker took
that was dropped, or lost on the way, is one the study never received: its record stands in for
it, as for a silent holder's, and its worker is not blamed (docs/security.md, "Junk on a study's
keys", "Junk on every key").

On a local farm (`own_workers`: the names of the workers it started) a result the broker took from
any other worker is refused and its job runs again on the farm's own. A worker that refuses a job
(it lacks a plug-in the job names) is no verdict on the run: the job runs elsewhere, and the run
stops (PluginError) only when no worker connected that has not refused it is left, or this process
lacks the plug-in too.

FarmClient is the Evaluator's face and composes the client's duties, each a module of its own:
its line to the farm (analytic.evaluators.farm_link: the session, the study, the model server,
the broker's presence), what Zenoh's thread takes in (farm_inbox), the pending jobs and their
submission (farm_jobs), the results confirmed and checked (farm_receive), the logs fetched in
parts (farm_logs) and which workers get the study's jobs (farm_workers).
"""

import logging
import queue
import time
from collections import deque
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import (
    EpisodeResult,
    Fetched,
    ReadLog,
    Wanted,
    accept_log,
)
from gainfarm.analytic.evaluators.farm_inbox import (
    DROPS_LOGGED_EVERY,
    MAX_HELD_BYTES,
    Arrival,
    Inbox,
)
from gainfarm.analytic.evaluators.farm_jobs import (
    RECHECK_SECONDS,
    SILENT_AFTER,
    SILENT_BATCH,
    SILENT_FRACTION,
    SUBMIT_CHUNK,
    Jobs,
)
from gainfarm.analytic.evaluators.farm_link import (
    ANSWER_SECONDS,
    BROKER_BACK,
    BROKER_GONE,
    FarmUnavailable,
    StudyLink,
)
from gainfarm.analytic.evaluators.farm_logs import FETCHES_AT_ONCE, Logs
from gainfarm.analytic.evaluators.farm_receive import CONFIRM_BATCH, TAKEN_PATIENCE, Receiver
from gainfarm.analytic.evaluators.farm_workers import Workers
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.wire import BrokerStatus, Submission

# The client's settings, where they were before its duties had modules of their own, and are
# imported from still (the command lines, the benchmarks).
__all__ = [
    "ANSWER_SECONDS",
    "CONFIRM_BATCH",
    "DEFAULT_ATTEMPTS",
    "DEFAULT_DEADLINE",
    "DROPS_LOGGED_EVERY",
    "FETCHES_AT_ONCE",
    "MAX_HELD_BYTES",
    "RECHECK_SECONDS",
    "SILENT_AFTER",
    "SILENT_BATCH",
    "SILENT_FRACTION",
    "SUBMIT_CHUNK",
    "TAKEN_PATIENCE",
    "FarmClient",
    "FarmUnavailable",
]

log = logging.getLogger("gainfarm.analytic")

DEFAULT_DEADLINE = 600.0  # s from (re)submission: a backstop; leases and liveliness act sooner
DEFAULT_ATTEMPTS = 3


class FarmClient:
    """An Evaluator whose jobs run on a farm of any size (the module's doc says how)."""

    def __init__(
        self,
        connect: Sequence[str],
        study: str,
        run_dir: Path,
        *,
        deadline: float = DEFAULT_DEADLINE,
        attempts: int = DEFAULT_ATTEMPTS,
        identity: TlsIdentity | None = None,
        models: Mapping[str, bytes] | None = None,
        keep_logs: bool = True,
        read_log: ReadLog = accept_log,
        trusted: bool = False,
        max_held_bytes: int = MAX_HELD_BYTES,
        own_workers: Collection[str] | None = None,
    ):
        """`models`: the feed-forward models (file bytes by SHA-256) the study's jobs may name;
        the client serves them to the workers that ask, in parts. `keep_logs`: every job's log
        is fetched from its worker as soon as its result is confirmed, checked, scored here
        again and kept; else each result brings the scores its worker computed, and `fetch`
        brings the logs wanted.
        `read_log` checks, keeps and scores a log (another only for simulated workers, whose
        "logs" are not episodes: bench/campaign.py --simulated). `trusted`: the farm's workers are
        this process's own (a local farm started for it), so a run has nothing to referee.
        `max_held_bytes`: the bytes of results held before the broker confirms them.
        `own_workers`: the names of the workers of a local farm started for this client; a
        result from any other worker is refused, and the job runs again on these (`strangers`)."""
        Submission(study=study, jobs=[])  # validates the name before it becomes a key
        self.study = study
        self.trusted = trusted
        self.models = dict(models or {})
        self.log_dir = Path(run_dir) / "episodes"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.keep_logs = keep_logs
        self._next_chase = 0.0  # when to look for overdue jobs next
        self._link = StudyLink(connect, study, identity, self.models)
        self.session = self._link.session
        self._workers = Workers(self._link.status, own_workers)
        self.own_workers = self._workers.own_workers
        self._jobs = Jobs(self._link, self._workers, deadline, attempts)
        self._inbox = Inbox(study, self._jobs.pending, max_held_bytes)
        self._logs = Logs(self._link, self._workers, self.log_dir, read_log, trusted)
        self._receiver = Receiver(
            self._jobs, self._inbox, self._workers, self._logs, self.log_dir, read_log
        )
        try:
            self._link.open_study(connect, self._inbox.on_result, self._inbox.put)
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> "FarmClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._link.close()  # undeclares the token: the broker drops what is still queued

    # --- what the client has seen, for progress lines and tests ----------------------------------

    @property
    def waiting(self) -> str | None:
        """Why the client is waiting for the broker, if it is."""
        return self._link.waiting

    @property
    def on_wait(self) -> Callable[[str | None], None]:
        """Told each time `waiting` changes (a progress line says so): the reason, or None."""
        return self._link.on_wait

    @on_wait.setter
    def on_wait(self, told: Callable[[str | None], None]) -> None:
        self._link.on_wait = told

    @property
    def duplicates(self) -> int:
        """Results for jobs no longer waited for."""
        return self._inbox.duplicates

    @property
    def ignored(self) -> int:
        """Samples that were no result of this study."""
        return self._inbox.ignored

    @property
    def unconfirmed(self) -> int:
        """Results the broker did not take: forged, or from a stale lease."""
        return self._inbox.unconfirmed

    @property
    def unheard(self) -> int:
        """Results the broker took that never came: taken from its record."""
        return self._inbox.unheard

    @property
    def dropped(self) -> int:
        """Results for pending jobs not held: max_held_bytes was full."""
        return self._inbox.dropped

    @property
    def held_bytes(self) -> int:
        """Bytes of results held now, before the broker confirms them."""
        return self._inbox.held_bytes

    @property
    def peak_held_bytes(self) -> int:
        return self._inbox.peak_held_bytes

    @property
    def pending(self) -> int:
        """Jobs submitted whose evaluation has not been handed out yet."""
        return len(self._jobs.pending) + len(self._jobs.ready)

    # --- the farm's workers -------------------------------------------------------------------

    def status(self) -> BrokerStatus:
        return self._link.status()

    @property
    def capacity(self) -> int:
        """The workers connected to the farm now: how many jobs can run at once."""
        return self.status().worker_count

    @property
    def trusted_capacity(self) -> int:
        """The workers connected now that may still run this study's jobs: neither distrusted
        nor left out (by name where the status lists them all, else by count). A broker that
        does not answer is no verdict: taken as one (the run goes on, and waits for it)."""
        return self._workers.trusted_capacity()

    def distrust(self, worker: str) -> None:
        """Give `worker` none of this study's jobs from now on, resubmissions included."""
        self._workers.distrusted.add(worker)

    @property
    def distrusted(self) -> frozenset[str]:
        """The workers given none of this study's jobs: named by `distrust`, or caught here
        claiming scores their logs do not have."""
        return frozenset(self._workers.distrusted)

    @property
    def strangers(self) -> frozenset[str]:
        """The workers outside `own_workers` whose results came (and were refused): given none of
        this study's jobs."""
        return frozenset(self._workers.strangers)

    @property
    def unheard_from(self) -> frozenset[str]:
        """The workers given none of this study's jobs because a result they handed in to the
        broker never came here."""
        return frozenset(self._workers.unheard_from)

    # --- the Evaluator ------------------------------------------------------------------------

    def submit(
        self,
        specs: Mapping[str, EpisodeSpec],
        avoid: Mapping[str, Sequence[str]] | None = None,
        *,
        keep_log: bool | None = None,
    ) -> None:
        """Queue one job per (job id, spec). A job id may not be pending already. `avoid` names,
        per job id, workers that may not run it (a replica must run elsewhere). `keep_log`:
        whether their logs are fetched as soon as their results are confirmed (default:
        `keep_logs`)."""
        keep = self.keep_logs if keep_log is None else keep_log
        clash = sorted(set(specs) & set(self._jobs.pending))
        if clash:
            raise ValueError(f"job ids already pending: {', '.join(clash[:5])}")
        unserved = {spec.feedforward for spec in specs.values()} - {None, *self.models}
        if unserved:
            raise ValueError(f"jobs name feed-forward models not served: {sorted(unserved)}")
        self._jobs.add(specs, avoid or {}, keep)

    def cancel(self, job_ids: Iterable[str]) -> None:
        """Stop waiting for these jobs; a result that still comes for one is counted as a
        duplicate and dropped. (The broker may still run them: the study's token decides.)"""
        dropped = set(job_ids)
        for job_id in dropped:
            self._jobs.pending.pop(job_id, None)
            self._receiver.forget(job_id)
        self._jobs.ready = deque(e for e in self._jobs.ready if e.job_id not in dropped)

    def results(self, timeout: float | None = None) -> Iterator[EpisodeResult]:
        """Yield evaluations as they complete, until none is pending (or `timeout` s pass)."""
        jobs, receiver = self._jobs, self._receiver
        give_up = None if timeout is None else time.monotonic() + timeout
        while jobs.pending or jobs.ready:
            while jobs.ready:
                yield jobs.ready.popleft()
            if not jobs.pending:
                break
            now = time.monotonic()
            if give_up is not None and now >= give_up:
                return
            wake = self._next_chase if give_up is None else min(self._next_chase, give_up)
            try:
                first = self._inbox.get(timeout=max(wake - now, 0.0))
                messages = [first, *self._inbox.drain(CONFIRM_BATCH)]
            except queue.Empty:
                messages = []
            for message in messages:
                if message == BROKER_BACK:
                    jobs.rejoin()
                elif message == BROKER_GONE:
                    jobs.wait_for_broker("the broker is gone")
                elif isinstance(message, Arrival):
                    receiver.arrive(message)
            receiver.ask_about(self._inbox.dropped_for())
            receiver.confirm()
            # Only after what arrived is taken in (a job whose result is here is not overdue);
            # and O(pending), so at most once a RECHECK_SECONDS however fast results come.
            if time.monotonic() >= self._next_chase:
                jobs.chase_overdue()
                receiver.ask_unheard()
                receiver.chase_taken()
                self._next_chase = time.monotonic() + RECHECK_SECONDS

    def fetch(
        self, wanted: Mapping[str, Wanted], simulate_again: bool = True
    ) -> dict[str, Fetched]:
        """The logs of these jobs, from the workers that keep them (each holder asked in turn;
        only bytes that hash to the wanted digest are taken, whoever answers), written to
        run_dir/episodes/<job id>.mcap and scored here (on a farm of this process's own
        workers, `trusted`, a log wanted with its claimed scores keeps them). A log no holder
        has any more (its worker is gone, or let it go) is simulated again, episodes being
        deterministic: as the job `<job id>-k<n>`, on any worker, its log sent with its result
        with `keep_logs`, else fetched from that worker (a log that cannot be had is a Fetched
        without one, and why); with `simulate_again` false, not simulated: a Fetched without
        one."""
        fetched, again = self._logs.take(wanted)
        if again and not simulate_again:
            gone = Fetched(None, None, None, "its holders have it no more")
            fetched.update(dict.fromkeys(again, gone))
        elif again:
            fetched.update(self._simulate_again(again))
        return fetched

    def _simulate_again(self, again: Mapping[str, Wanted]) -> dict[str, Fetched]:
        """Run these jobs again, as `<job id>-k<n>`, their logs taken as this client takes them:
        fetched with their results (`keep_logs`), or else from the worker that ran them here."""
        reruns = {}
        for job_id in again:
            number = 1
            while f"{job_id}-k{number}" in self._jobs.pending:
                number += 1
            reruns[f"{job_id}-k{number}"] = job_id
        log.warning("simulating %d episodes again: their logs are gone", len(reruns))
        self.submit({rerun: again[job_id].spec for rerun, job_id in reruns.items()})
        found: dict[str, EpisodeResult] = {}
        others: list[EpisodeResult] = []
        for result in self.results():
            if result.job_id in reruns:
                found[result.job_id] = result
                if len(found) == len(reruns):
                    break
            else:
                others.append(result)  # handed out later, as if it had come after
        self._jobs.ready.extendleft(reversed(others))
        fetched = {}
        for rerun, job_id in reruns.items():
            result = found.get(rerun)
            if result is None or result.digest is None:
                why = result.reason if result else "not simulated again"
                fetched[job_id] = Fetched(None, None, None, why or "not simulated again")
                continue
            if result.digest != again[job_id].digest:
                log.warning("%s simulated again is not the log its worker had made", job_id)
            path = self.log_dir / f"{job_id}.mcap"
            if result.log is not None:  # fetched with its result, checked and scored
                result.log.replace(path)
                scores = result.scores
            else:
                scores = self._logs.rerun_log(job_id, result, again[job_id].spec, path)
                if scores is None:
                    why = f"simulated again on {result.worker}, but its log was not had"
                    fetched[job_id] = Fetched(None, None, None, why)
                    continue
            fetched[job_id] = Fetched(path, scores, result.digest, source=result.worker)
        return fetched
