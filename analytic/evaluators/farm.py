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
"""

import hashlib
import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import zenoh

from gainfarm import plugins
from gainfarm.analytic.evaluators.evaluator import (
    EpisodeResult,
    EpisodeStatus,
    Fetched,
    ReadLog,
    Wanted,
    accept_log,
)
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.ask import ask
from gainfarm.edges.files import write_atomically
from gainfarm.edges.parts import fetch_parts, reply_part
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session, token_held
from gainfarm.plugins import PluginError
from gainfarm.schemas import keys
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.wire import (
    MAX_EPISODE_BYTES,
    MAX_MESSAGE_BYTES,
    Accepted,
    BadMessage,
    BrokerStatus,
    ConfirmReply,
    ConfirmRequest,
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
RECHECK_SECONDS = 1.0  # how often overdue jobs are looked for, and unconfirmed results asked about
CONFIRM_BATCH = 1000  # results confirmed in one question to the broker
# A job with no result this long after its submission is asked about (see the module's doc), then
# again after SILENT_FRACTION of its age (at least RECHECK_SECONDS later): a result withheld costs
# about that fraction of the wait more, and a deep queue's jobs are not all asked about at once:
# at most SILENT_BATCH of them, those asked about longest ago first, once a RECHECK_SECONDS.
SILENT_AFTER = 2.0  # s
SILENT_FRACTION = 0.25
SILENT_BATCH = 200
# The bytes of results held before the broker says which it took (in the inbox and arrived): a
# result is its attachment alone (a Result: about a kilobyte, at most a wire message), so this
# holds thousands; a flood of well-formed forgeries for pending jobs fills it, and what comes
# then is dropped until the broker has been asked (each inbox drain confirms at once).
MAX_HELD_BYTES = 4 * MAX_MESSAGE_BYTES
# How long the result the broker took for a job may take to reach us after the broker said so
# (a worker hands its result in, then puts it); then the broker's record stands in for it, or
# the job runs again.
TAKEN_PATIENCE = 1.0  # s
# Logs of confirmed results fetched at once (`keep_logs`), each in parts with a few in flight:
# a fetch is a round trip through the router to its worker, and one at a time made a `--keep all`
# run slower than when logs came with their results.
FETCHES_AT_ONCE = 4
DROPS_LOGGED_EVERY = 10.0  # s: samples dropped are logged at most this often, with their count


BROKER_BACK = "broker-back"  # inbox markers
BROKER_GONE = "broker-gone"


class FarmUnavailable(ConnectionError):
    """No broker answered, or the study is already open elsewhere."""


@dataclass
class _Pending:
    spec: EpisodeSpec
    deadline: float
    attempts: int = 1
    avoid: tuple[str, ...] = ()  # workers that may not run it
    keep_log: bool = True  # its log is fetched as soon as its result is confirmed
    submitted: float = 0.0  # monotonic time of its first submission
    ask_at: float = 0.0  # when to ask the broker about it if no result has come (SILENT_AFTER)
    dropped_here: bool = False  # a result of it was dropped here, max_held_bytes being full


@dataclass(frozen=True)
class _Arrival:
    """A result as it arrived, waiting for the broker to confirm it."""

    result: Result
    held: int  # bytes counted against MAX_HELD_BYTES until it is let go
    taken: Accepted | None = None  # the result the broker said it took, if this is that one


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
        self.deadline = deadline
        self.attempts = attempts
        self.keep_logs = keep_logs
        self.read_log = read_log
        self.max_held_bytes = max_held_bytes
        self.duplicates = 0
        self.ignored = 0
        self.unconfirmed = 0  # results the broker did not take: forged, or from a stale lease
        self.unheard = 0  # results the broker took that never came: taken from its record
        self.dropped = 0  # results for pending jobs not held: max_held_bytes was full
        self.held_bytes = 0  # bytes of results held now, before the broker confirms them
        self.peak_held_bytes = 0
        self.waiting: str | None = None  # why the client is waiting for the broker, if it is
        # Told each time `waiting` changes (a progress line says so); the reason, or None.
        self.on_wait: Callable[[str | None], None] = lambda why: None
        self._pending: dict[str, _Pending] = {}
        self._ready: deque[EpisodeResult] = deque()
        self._next_chase = 0.0  # when to look for overdue jobs next
        self._arrived: dict[str, list[_Arrival]] = {}  # by job id, until the broker confirms
        # What the broker said it took, for jobs whose result has not come (yet), and when.
        self._taken: dict[str, tuple[Accepted, float]] = {}
        self._dropped_for: set[str] = set()  # jobs a result was dropped for: ask the broker
        self._lock = threading.Lock()  # the above and the counters, shared with Zenoh's thread
        self._drops_logged = 0.0
        self._distrusted: set[str] = set()
        self._unheard_from: set[str] = set()
        self.own_workers = None if own_workers is None else frozenset(own_workers)
        self._strangers: set[str] = set()
        # Who refused jobs needing what (a trajectory kind and objectives: `_needs`): a worker
        # that lacks a plug-in gets no more jobs that need it.
        self._refused_by: dict[tuple[str, ...], set[str]] = {}
        self._inbox: queue.SimpleQueue[_Arrival | str] = queue.SimpleQueue()
        # Serves (the model key, in parts), takes results, asks the broker and fetches logs in
        # parts: no message it takes is larger than a wire message (docs/security.md).
        self.session = open_session(
            "client", connect=connect, identity=identity, max_message_bytes=SERVING_SESSION_BYTES
        )
        try:
            self._open_study(connect)
        except BaseException:
            self.close()
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
        return self.status().worker_count

    @property
    def trusted_capacity(self) -> int:
        """The workers connected now that may still run this study's jobs: neither distrusted
        nor left out (by name where the status lists them all, else by count). A broker that
        does not answer is no verdict: taken as one (the run goes on, and waits for it)."""
        try:
            status = self.status()
        except (BrokerUnavailable, BadMessage):
            return 1
        return self._able(status, self._barred())

    def _barred(self) -> set[str]:
        """The workers given none of this study's jobs."""
        return self._distrusted | self._unheard_from | self._strangers

    def _able(self, status: BrokerStatus, barred: set[str]) -> int:
        """How many workers connected now are not `barred` (and are this client's own, if it
        has `own_workers`): by name where the status lists them all, else by count."""
        names = {worker.name for worker in status.workers}
        if len(names) == status.worker_count:
            if self.own_workers is not None:
                names &= self.own_workers
            return len(names - barred)
        return max(status.worker_count - len(barred), 0)

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
        clash = sorted(set(specs) & set(self._pending))
        if clash:
            raise ValueError(f"job ids already pending: {', '.join(clash[:5])}")
        unserved = {spec.feedforward for spec in specs.values()} - {None, *self.models}
        if unserved:
            raise ValueError(f"jobs name feed-forward models not served: {sorted(unserved)}")
        avoid = avoid or {}
        now = time.monotonic()
        for job_id, spec in specs.items():
            self._pending[job_id] = _Pending(
                spec,
                now + self.deadline,
                avoid=tuple(avoid.get(job_id, ())),
                keep_log=keep,
                submitted=now,
                ask_at=now + SILENT_AFTER,
            )
        self._send([self._job(job_id) for job_id in specs])

    def distrust(self, worker: str) -> None:
        """Give `worker` none of this study's jobs from now on, resubmissions included."""
        self._distrusted.add(worker)

    @property
    def distrusted(self) -> frozenset[str]:
        """The workers given none of this study's jobs: named by `distrust`, or caught here
        claiming scores their logs do not have."""
        return frozenset(self._distrusted)

    @property
    def strangers(self) -> frozenset[str]:
        """The workers outside `own_workers` whose results came (and were refused): given none of
        this study's jobs."""
        return frozenset(self._strangers)

    @property
    def unheard_from(self) -> frozenset[str]:
        """The workers given none of this study's jobs because a result they handed in to the
        broker never came here."""
        return frozenset(self._unheard_from)

    def cancel(self, job_ids: Iterable[str]) -> None:
        """Stop waiting for these jobs; a result that still comes for one is counted as a
        duplicate and dropped. (The broker may still run them: the study's token decides.)"""
        dropped = set(job_ids)
        for job_id in dropped:
            self._pending.pop(job_id, None)
            self._release(self._arrived.pop(job_id, []))
            with self._lock:
                self._taken.pop(job_id, None)
        self._ready = deque(e for e in self._ready if e.job_id not in dropped)

    def results(self, timeout: float | None = None) -> Iterator[EpisodeResult]:
        """Yield evaluations as they complete, until none is pending (or `timeout` s pass)."""
        give_up = None if timeout is None else time.monotonic() + timeout
        while self._pending or self._ready:
            while self._ready:
                yield self._ready.popleft()
            if not self._pending:
                break
            now = time.monotonic()
            if give_up is not None and now >= give_up:
                return
            wake = self._next_chase if give_up is None else min(self._next_chase, give_up)
            try:
                messages = [self._inbox.get(timeout=max(wake - now, 0.0)), *self._drain()]
            except queue.Empty:
                messages = []
            for message in messages:
                if message == BROKER_BACK:
                    self._rejoin()
                elif message == BROKER_GONE:
                    self._broker_gone()
                elif isinstance(message, _Arrival):
                    self._arrive(message)
            with self._lock:
                dropped, self._dropped_for = self._dropped_for, set()
            for job_id in dropped & self._pending.keys():
                self._arrived.setdefault(job_id, [])  # the broker tells which result it took
            self._confirm()
            # Only after what arrived is taken in (a job whose result is here is not overdue);
            # and O(pending), so at most once a RECHECK_SECONDS however fast results come.
            if time.monotonic() >= self._next_chase:
                self._chase_overdue()
                self._ask_unheard()
                self._chase_taken()
                self._next_chase = time.monotonic() + RECHECK_SECONDS

    def _drain(self) -> list[_Arrival | str]:
        """Whatever else is in the inbox now: its results are confirmed in one question."""
        messages = []
        while len(messages) < CONFIRM_BATCH:
            try:
                messages.append(self._inbox.get_nowait())
            except queue.Empty:
                break
        return messages

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
        fetched: dict[str, Fetched] = {}
        again: dict[str, Wanted] = {}
        for job_id, want in wanted.items():
            content, holder = self._fetch_log(want)
            if content is not None:
                path = self.log_dir / f"{job_id}.mcap"
                if self.trusted and want.scores is not None:
                    # Its own worker's bytes (their digest checked): the scores it claimed are
                    # the log's, and decoding and scoring it again would check nothing.
                    write_atomically(path, content)
                    fetched[job_id] = Fetched(path, want.scores, want.digest, source=holder)
                    continue
                try:
                    scores = self.read_log(content, want.spec, path, f"log of {job_id}")
                except NotAnEpisodeLog as error:  # the right bytes of the wrong episode
                    log.warning("fetched log of %s: %s", job_id, error)
                else:
                    fetched[job_id] = Fetched(path, scores, want.digest, source=holder)
                    continue
            again[job_id] = want
        if again and not simulate_again:
            gone = Fetched(None, None, None, "its holders have it no more")
            fetched.update(dict.fromkeys(again, gone))
        elif again:
            fetched.update(self._simulate_again(again))
        return fetched

    def _fetch_log(self, want: Wanted, limit: int = MAX_EPISODE_BYTES) -> tuple[bytes | None, str]:
        """The log's bytes and the holder that had them, or None. Each holder in turn is asked
        for it in parts, `limit` bytes at most; one that answers badly (schemas.parts) or with
        other bytes is skipped."""
        for holder in want.holders:
            try:
                key = keys.log(self.study, holder, want.digest)
                content = fetch_parts(self.session, key, limit, ANSWER_SECONDS)
            except zenoh.ZError as error:  # e.g. an empty or bad holder name
                log.warning("cannot ask %r for a log: %s", holder, error)
                continue
            except BadMessage as error:
                log.warning("ignored a log from %s: %s", holder, error)
                continue
            if content is None:
                continue  # it has it no more: ask the next holder
            if hashlib.sha256(content).hexdigest() == want.digest:
                return content, holder
            log.warning("ignored a log on %s: its bytes are not the ones the broker took", key)
        return None, ""

    def _simulate_again(self, again: Mapping[str, Wanted]) -> dict[str, Fetched]:
        """Run these jobs again, as `<job id>-k<n>`, their logs taken as this client takes them:
        fetched with their results (`keep_logs`), or else from the worker that ran them here."""
        reruns = {}
        for job_id in again:
            number = 1
            while f"{job_id}-k{number}" in self._pending:
                number += 1
            reruns[f"{job_id}-k{number}"] = job_id
        log.warning("simulating %d episodes again: their logs are gone", len(reruns))
        self.submit({rerun: again[job_id].spec for rerun, job_id in reruns.items()})
        found: dict[str, EpisodeResult] = {}
        others: list[EpisodeResult] = []
        for evaluation in self.results():
            if evaluation.job_id in reruns:
                found[evaluation.job_id] = evaluation
                if len(found) == len(reruns):
                    break
            else:
                others.append(evaluation)  # handed out later, as if it had come after
        self._ready.extendleft(reversed(others))
        fetched = {}
        for rerun, job_id in reruns.items():
            evaluation = found.get(rerun)
            if evaluation is None or evaluation.digest is None:
                why = evaluation.reason if evaluation else "not simulated again"
                fetched[job_id] = Fetched(None, None, None, why or "not simulated again")
                continue
            if evaluation.digest != again[job_id].digest:
                log.warning("%s simulated again is not the log its worker had made", job_id)
            path = self.log_dir / f"{job_id}.mcap"
            if evaluation.log is not None:  # fetched with its result, checked and scored
                evaluation.log.replace(path)
                scores = evaluation.scores
            else:
                scores = self._fetch_rerun(job_id, evaluation, again[job_id].spec, path)
                if scores is None:
                    why = f"simulated again on {evaluation.worker}, but its log was not had"
                    fetched[job_id] = Fetched(None, None, None, why)
                    continue
            fetched[job_id] = Fetched(path, scores, evaluation.digest, source=evaluation.worker)
        return fetched

    def _fetch_rerun(
        self, job_id: str, evaluation: EpisodeResult, spec: EpisodeSpec, path: Path
    ) -> Scores | None:
        """The log of a job run again, from the worker that ran it (by its digest), kept at
        `path` and scored here; None if it cannot be had. A worker whose log does not score as
        it claimed is distrusted."""
        assert evaluation.digest is not None
        want = Wanted(spec, evaluation.digest, (evaluation.worker,))
        content, _ = self._fetch_log(want)
        if content is None:
            log.warning("%s simulated again: %s no longer has its log", job_id, evaluation.worker)
            return None
        try:
            scores = self.read_log(content, spec, path, f"log of {job_id} simulated again")
        except NotAnEpisodeLog as error:
            log.warning("%s simulated again: %s", job_id, error)
            return None
        if scores != evaluation.scores:
            self.distrust(evaluation.worker)
            log.warning(
                "%s simulated again: %s claimed scores its log has not", job_id, evaluation.worker
            )
        return scores

    # --- inside ----------------------------------------------------------------------------

    def _open_study(self, connect: Sequence[str]) -> None:
        token_key = keys.alive_study(self.study)
        self._subscriber = self.session.declare_subscriber(
            keys.study_results(self.study), self._on_result
        )
        # Asked after the subscriber: once answered, the router knows the subscriber (one link,
        # in order), before the token below lets any job be submitted.
        if token_held(self.session, token_key):
            raise FarmUnavailable(f"study {self.study!r} is already open in another process")
        # Declared whatever `models` holds now: an experiment adds a run's model to a client
        # it has made (analytic.experiments.base.serving), and the workers must find it.
        self._model_server = self.session.declare_queryable(
            keys.model(self.study, "*"), self._on_model_query
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
            self._inbox.put(BROKER_BACK)
        else:
            self._inbox.put(BROKER_GONE)

    def _broker_gone(self) -> None:
        self._wait_for_broker("the broker is gone")

    def _wait_for_broker(self, why: str) -> None:
        """No answer from the broker is no verdict on any job: wait, saying so, and spend no
        attempts until it answers again."""
        if self.waiting is None:  # said once, with the first reason, until it answers again
            log.warning("%s; waiting for it (%d jobs pending)", why, len(self._pending))
            self.waiting = why
            self.on_wait(why)
        later = time.monotonic() + self.deadline
        for pending in self._pending.values():
            pending.deadline = max(pending.deadline, later)

    def _broker_answers(self) -> bool:
        """Whether the broker answers now; clears `waiting` when it does again."""
        answered = ask(self.session, keys.STATUS, timeout=ANSWER_SECONDS) is not None
        if answered and self.waiting is not None:
            log.warning("the broker answers again")
            self.waiting = None
            self.on_wait(None)
        return answered

    def _rejoin(self) -> None:
        """A new broker knows none of our jobs: once it knows the study, submit them all again.
        Its restart lost them, the worker did not fail them: no attempt is counted."""
        log.warning("a broker (re)started; resubmitting %d pending jobs", len(self._pending))
        if self.waiting is not None:
            self.waiting = None
            self.on_wait(None)
        try:
            self._await_study("the restarted broker")
        except FarmUnavailable as error:
            self._wait_for_broker(str(error))
            return
        now = time.monotonic()
        for pending in self._pending.values():
            pending.deadline = now + self.deadline
        self._send([self._job(job_id) for job_id in self._pending])

    def _job(self, job_id: str) -> Job:
        pending = self._pending[job_id]
        refusers = self._refused_by.get(_needs(pending.spec), set())
        avoid = sorted({*pending.avoid, *self._barred(), *refusers})
        return Job(job_id=job_id, spec=pending.spec, avoid=avoid, keep_log=pending.keep_log)

    def _on_model_query(self, query: zenoh.Query) -> None:
        wanted = keys.last_chunk(str(query.key_expr))
        if wanted in self.models:
            reply_part(query, self.models[wanted])
        else:
            query.reply_err(f"study {self.study} has no model {wanted[:64]}")

    def _on_result(self, sample: zenoh.Sample) -> None:
        """Runs on Zenoh's thread for every sample on the study's keys, whoever put it: reads
        the attachment (a Result, at most MAX_MESSAGE_BYTES) and holds it only for a pending
        job, with no payload (a result carries no log), within max_held_bytes. Never raises:
        whatever the sample, it is held or dropped."""
        attachment = sample.attachment
        try:
            if attachment is None:
                raise BadMessage("no attachment")
            if len(attachment) > MAX_MESSAGE_BYTES:
                raise BadMessage(f"a {len(attachment)}-byte attachment")
            if len(sample.payload):
                raise BadMessage(f"a {len(sample.payload)}-byte payload: a result carries no log")
            raw = attachment.to_bytes()
            result = decode(Result, raw)
        except BadMessage as error:
            return self._drop("ignored", f"not a result ({error})")
        if result.study != self.study:
            return self._drop("ignored", f"a result of study {result.study[:64]!r}")
        pending = self._pending.get(result.job_id)
        if pending is None:  # already evaluated (or never submitted here)
            return self._drop("duplicates")
        held = len(raw)
        with self._lock:
            taken = self._taken.get(result.job_id)
            if taken is not None and not _matches(result, taken[0]):
                self.unconfirmed += 1  # the broker took another: this one is not held
                return
            if taken is None and self.held_bytes + held > self.max_held_bytes:
                self.dropped += 1
                self._dropped_for.add(result.job_id)
                pending.dropped_here = True
                return self._log_drop(f"a result for {result.job_id}: {self.held_bytes} bytes held")
            if taken is not None:  # the one the broker took: held whatever the budget, once
                del self._taken[result.job_id]
            self.held_bytes += held
            self.peak_held_bytes = max(self.peak_held_bytes, self.held_bytes)
        self._inbox.put(_Arrival(result, held, taken and taken[0]))

    def _drop(self, counter: str, why: str = "") -> None:
        with self._lock:
            setattr(self, counter, getattr(self, counter) + 1)
            if why:
                self._log_drop(why)

    def _log_drop(self, why: str) -> None:
        """Say why a sample was dropped, at most once a DROPS_LOGGED_EVERY (under the lock)."""
        now = time.monotonic()
        if now >= self._drops_logged + DROPS_LOGGED_EVERY:
            self._drops_logged = now
            log.warning(
                "dropped %s (so far: %d ignored, %d not waited for, %d not held)",
                why,
                self.ignored,
                self.duplicates,
                self.dropped,
            )

    def _release(self, arrivals: Iterable[_Arrival]) -> None:
        freed = sum(arrival.held for arrival in arrivals)
        if freed:
            with self._lock:
                self.held_bytes -= freed

    def _send(self, jobs: list[Job]) -> set[str]:
        """Submit `jobs`; return the ids the broker did not newly queue: those it still had
        queued or running, those it deferred (its queue is full) and those it did not hear."""
        not_queued: set[str] = set()
        for start in range(0, len(jobs), SUBMIT_CHUNK):
            chunk = jobs[start : start + SUBMIT_CHUNK]
            reply = self._ask(Submission(study=self.study, jobs=chunk))
            if reply is None:  # the deadline will resubmit them, once the broker answers
                self._wait_for_broker("the broker did not answer a submission")
                not_queued.update(job.job_id for job in chunk)
                continue
            not_queued.update(reply.already_pending)
            not_queued.update(reply.deferred)
            if reply.deferred:  # a full queue is no verdict: submit them again soon
                log.warning("the broker deferred %d jobs: its queue is full", len(reply.deferred))
                soon = time.monotonic() + RECHECK_SECONDS
                for job_id in reply.deferred:
                    if job_id in self._pending:
                        self._pending[job_id].deadline = soon
            for rejection in reply.rejected:
                pending = self._pending.pop(rejection.job_id, None)
                if pending is not None:
                    self._ready.append(self._failed(rejection.job_id, pending, rejection.reason))
        return not_queued

    def _ask(self, submission: Submission) -> SubmitReply | None:
        answer = ask(
            self.session, keys.submit(self.study), submission.to_bytes(), timeout=ANSWER_SECONDS
        )
        if answer is None:
            return None
        if answer.payload is None:
            raise BadMessage(f"the broker refused a submission: {answer.error}")
        return decode(SubmitReply, answer.payload)

    def _chase_overdue(self) -> None:
        """Resubmit every job past its deadline; give up on those out of attempts. Only while
        the broker answers: without it, no job's time runs out."""
        now = time.monotonic()
        overdue = [job_id for job_id, pending in self._pending.items() if pending.deadline <= now]
        if not overdue:
            return
        if not self._broker_answers():
            self._wait_for_broker("no answer from the broker")
            return
        now = time.monotonic()
        again = []
        for job_id in overdue:
            pending = self._pending[job_id]
            if pending.attempts >= self.attempts:
                del self._pending[job_id]
                reason = f"no result after {pending.attempts} attempts"
                self._ready.append(self._failed(job_id, pending, reason, EpisodeStatus.lost))
                continue
            pending.attempts += 1
            pending.deadline = now + self.deadline
            again.append(self._job(job_id))
        if again:
            log.warning("resubmitting %d overdue jobs", len(again))
            for job_id in self._send(again):  # merely slow, not lost: not another attempt
                if job_id in self._pending:
                    self._pending[job_id].attempts -= 1

    def _ask_unheard(self) -> None:
        """Ask the broker about jobs whose results have not come in a while (those asked about
        longest ago first, SILENT_BATCH at most). A result it took for one is waited for
        TAKEN_PATIENCE more, in case it is on its way here (`_chase_taken`)."""
        if self.waiting is not None:  # the broker is not answering: _chase_overdue asks
            return
        now = time.monotonic()
        with self._lock:
            told = set(self._taken)
        due = [
            (pending.ask_at, job_id)
            for job_id, pending in self._pending.items()
            if pending.ask_at <= now and job_id not in self._arrived and job_id not in told
        ]
        if not due:
            return
        job_ids = [job_id for _, job_id in sorted(due)[:SILENT_BATCH]]
        for job_id in job_ids:
            pending = self._pending[job_id]
            age = now - pending.submitted
            pending.ask_at = now + max(RECHECK_SECONDS, SILENT_FRACTION * age)
        request = ConfirmRequest(study=self.study, job_ids=job_ids)
        answer = ask(self.session, keys.confirm(self.study), request.to_bytes(), ANSWER_SECONDS)
        if answer is None:
            self._wait_for_broker("the broker did not answer about unheard results")
            return
        try:
            if answer.payload is None:
                raise BadMessage(f"the broker refused to confirm results: {answer.error}")
            reply = decode(ConfirmReply, answer.payload)
        except BadMessage as error:
            log.warning("%s", error)
            return
        asked = set(job_ids)
        with self._lock:  # the broker forgets what it has told: remember it until it comes
            for accepted in reply.accepted:
                if accepted.job_id in asked:
                    self._taken[accepted.job_id] = (accepted, now)

    def _from_record(self, accepted: Accepted) -> EpisodeResult | None:
        """The evaluation of a job whose result the broker took but which never came here: the
        scores as handed in, the log left with the worker. A job that wanted its log, or whose
        record has no scores, runs again elsewhere (None). Unless this client dropped the result
        itself (its budget was full: `max_held_bytes`), its worker is left out (`_leave_out`)."""
        pending = self._pending[accepted.job_id]
        if self._stranger(accepted.worker):
            return self._turn_away(accepted.job_id, accepted.worker, pending)
        blamed = not pending.dropped_here
        if blamed:
            self.unheard += 1
            self._leave_out(accepted.worker)
        if accepted.scores is None or pending.keep_log:
            if not blamed:  # dropped here: run again, no attempt spent
                log.warning(
                    "job %s: its result was dropped here; running it again", accepted.job_id
                )
                pending.dropped_here = False
                pending.deadline = time.monotonic() + self.deadline
                self._send([self._job(accepted.job_id)])
                return None
            pending.avoid = tuple(sorted({*pending.avoid, accepted.worker}))
            what = "its log" if accepted.scores is not None else "why it did not run"
            reason = f"its result never came, and the broker's record lacks {what}"
            return self._run_again(accepted.job_id, accepted.worker, pending, reason)
        if blamed:
            log.warning(
                "job %s: %s handed its result in but never sent it; taken from the broker's record",
                accepted.job_id,
                accepted.worker,
            )
        del self._pending[accepted.job_id]
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

    def _leave_out(self, worker: str) -> None:
        """Give `worker`, whose result never came, none of this study's jobs from now on: unless
        it is the last worker left to run them (its result may only have been late)."""
        if worker in self._unheard_from:
            return
        try:
            connected = self.status().worker_count
        except (BrokerUnavailable, BadMessage):
            return
        if connected > len(self._barred() | {worker}):
            self._unheard_from.add(worker)
            log.warning("%s gets no more of this study's jobs: its results do not come", worker)

    def _arrive(self, arrival: _Arrival) -> None:
        """Keep a result as it arrives for the broker to confirm; or take it, if it is the one
        the broker already said it took."""
        job_id = arrival.result.job_id
        if job_id not in self._pending:  # evaluated or cancelled since it came
            self._release([arrival])
            with self._lock:
                self.duplicates += 1
            return
        taken = arrival.taken
        if taken is None:  # the broker may have said so while it waited in the inbox
            with self._lock:
                told = self._taken.get(job_id)
                if told is not None and _matches(arrival.result, told[0]):
                    taken = self._taken.pop(job_id)[0]
        if taken is None:
            self._arrived.setdefault(job_id, []).append(arrival)
            return
        self._release([arrival])
        evaluation = self._receive(arrival)
        if evaluation is not None:
            self._ready.append(evaluation)

    def _chase_taken(self) -> None:
        """A result the broker took that has not come within TAKEN_PATIENCE of its saying so
        (withheld by a silent holder, lost on the way, or dropped here with max_held_bytes
        full): the broker's record stands in for it (`_from_record`)."""
        now = time.monotonic()
        with self._lock:
            lost = [j for j, (_, since) in self._taken.items() if now - since >= TAKEN_PATIENCE]
            records = [self._taken.pop(job_id)[0] for job_id in lost]
        for accepted in records:
            if accepted.job_id in self._pending:
                evaluation = self._from_record(accepted)
                if evaluation is not None:
                    self._ready.append(evaluation)

    def _confirm(self) -> None:
        """Ask the broker which of the arrived results it took; each job's confirmed one is
        its evaluation, and every other is ignored. Unanswered: they wait for the next ask."""
        if not self._arrived:
            return
        job_ids = list(self._arrived)[:CONFIRM_BATCH]
        request = ConfirmRequest(study=self.study, job_ids=job_ids)
        answer = ask(self.session, keys.confirm(self.study), request.to_bytes(), ANSWER_SECONDS)
        if answer is None:
            self._wait_for_broker("the broker did not confirm results")
            return
        try:
            if answer.payload is None:
                raise BadMessage(f"the broker refused to confirm results: {answer.error}")
            reply = decode(ConfirmReply, answer.payload)
        except BadMessage as error:
            log.warning("%s", error)
            return
        taken = {accepted.job_id: accepted for accepted in reply.accepted}
        now = time.monotonic()
        received: list[_Arrival] = []  # confirmed: evaluated below, their logs fetched in batches
        for job_id in job_ids:
            arrivals = self._arrived.pop(job_id)
            self._release(arrivals)
            accepted = taken.get(job_id)
            confirmed = [a for a in arrivals if accepted and _matches(a.result, accepted)]
            others = len(arrivals) - min(len(confirmed), 1)
            if others:
                with self._lock:
                    self.unconfirmed += others
                    self._log_drop(f"{others} results for {job_id}: not the one the broker took")
            if accepted is not None and not confirmed and job_id in self._pending:
                # The broker forgets what it has told: remember it until that result comes.
                with self._lock:
                    self._taken[job_id] = (accepted, now)
            if confirmed and job_id in self._pending:
                received.append(confirmed[0])
        for batch in self._fetch_batches(received):
            logs = self._fetch_logs(batch)
            for arrival in batch:
                if arrival.result.job_id in self._pending:
                    evaluation = self._receive(arrival, logs)
                    if evaluation is not None:
                        self._ready.append(evaluation)

    def _wants_log(self, result: Result) -> bool:
        """Whether a confirmed result's log is to be fetched with it (`keep_log`, it ran)."""
        pending = self._pending.get(result.job_id)
        return (
            pending is not None
            and pending.keep_log
            and result.scores is not None
            and not self._stranger(result.worker)
        )

    def _fetch_batches(self, arrivals: list[_Arrival]) -> Iterator[list[_Arrival]]:
        """`arrivals` in turn, in batches whose logs are fetched at once: FETCHES_AT_ONCE at
        most, and logs that say they add up to MAX_EPISODE_BYTES at most (one largest log), so
        what is held stays as before the logs came in parts."""
        batch: list[_Arrival] = []
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

    def _fetch_logs(self, batch: list[_Arrival]) -> dict[str, bytes | None]:
        """The logs of these confirmed results, by job id, fetched at once from their workers
        (each within the size its result says)."""
        wanted = [arrival.result for arrival in batch if self._wants_log(arrival.result)]
        if not wanted:
            return {}

        def fetch(result: Result) -> bytes | None:
            want = Wanted(self._pending[result.job_id].spec, result.digest, (result.worker,))
            return self._fetch_log(want, result.episode_bytes)[0]

        with ThreadPoolExecutor(max_workers=len(wanted)) as pool:
            return dict(zip([r.job_id for r in wanted], pool.map(fetch, wanted), strict=True))

    def _receive(
        self, arrival: _Arrival, fetched: Mapping[str, bytes | None] | None = None
    ) -> EpisodeResult | None:
        """The evaluation a confirmed result makes; with `keep_log`, its log from its worker, in
        `fetched` (by job id: the log, or None if it could not be had) or fetched here (None if
        it cannot be had or is unusable: it runs again)."""
        result = arrival.result
        pending = self._pending[result.job_id]
        common = dict(
            job_id=result.job_id,
            spec=pending.spec,
            worker=result.worker,
            attempts=pending.attempts,
            timings=result.timings,
            reason=result.reason,
        )
        if self._stranger(result.worker):
            return self._turn_away(result.job_id, result.worker, pending)
        if result.status == JobStatus.refused:  # the worker lacks a plug-in
            return self._refused(result, pending)
        if result.status == JobStatus.failed:
            del self._pending[result.job_id]
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
            del self._pending[result.job_id]
            return EpisodeResult(**ran, scores=claimed, log=None)
        path = self.log_dir / f"{result.job_id}.mcap"
        if fetched is not None and result.job_id in fetched:
            content = fetched[result.job_id]
        else:
            want = Wanted(pending.spec, result.digest, (result.worker,))
            content, _ = self._fetch_log(want, result.episode_bytes)
        if content is None:  # gone already (its store was full), or not served as the rules say
            reason = f"its log could not be fetched from {result.worker}"
            return self._run_again(result.job_id, result.worker, pending, reason)
        try:
            if len(content) != result.episode_bytes:
                raise NotAnEpisodeLog(f"{len(content)} bytes, not the {result.episode_bytes} sent")
            source = f"episode of {result.job_id} from {result.worker}"
            scores = self.read_log(content, pending.spec, path, source)
        except NotAnEpisodeLog as error:
            reason = f"unusable episode log: {error}"
            return self._run_again(result.job_id, result.worker, pending, reason)
        if scores != claimed:  # an honest log, false scores: the worker is not to be trusted
            path.unlink(missing_ok=True)
            self.distrust(result.worker)
            reason = f"its scores are not its log's ({result.worker} is distrusted)"
            return self._run_again(result.job_id, result.worker, pending, reason)
        del self._pending[result.job_id]
        return EpisodeResult(**ran, scores=scores, log=path)

    def _stranger(self, worker: str) -> bool:
        """Whether `worker` is not one this client's local farm started."""
        return self.own_workers is not None and worker not in self.own_workers

    def _turn_away(self, job_id: str, worker: str, pending: _Pending) -> None:
        """Refuse a result from a worker this client's local farm did not start (said once per
        worker): the job runs again on the farm's own, no attempt spent (a stranger cannot use
        them up), and the stranger gets none of the study's jobs."""
        if worker not in self._strangers:
            self._strangers.add(worker)
            why = "which this local farm did not start: refused"
            log.warning("result from worker %s, %s", worker, why)
        pending.avoid = tuple(sorted({*pending.avoid, worker}))
        self._resend(job_id, pending)

    def _refused(self, result: Result, pending: _Pending) -> None:
        """A worker refused the job, lacking a plug-in it needs: not the job's outcome while
        another worker may run it. PluginError, naming the worker and the plug-in, if this
        process lacks it too, or no worker connected that has not refused it is left."""
        reason = f"worker {result.worker} refused job {result.job_id}: {result.reason}"
        self._refused_by.setdefault(_needs(pending.spec), set()).add(result.worker)
        pending.avoid = tuple(sorted({*pending.avoid, result.worker}))
        if _lacked_here(pending.spec) or not self._others_for(pending):
            raise PluginError(reason)
        log.warning("%s; running it on another worker", reason)
        self._resend(result.job_id, pending)

    def _others_for(self, pending: _Pending) -> bool:
        """Whether a worker connected now may run the job: not avoided by it, nor barred. A
        broker that does not answer is no verdict: taken as yes (the job waits for it)."""
        try:
            status = self.status()
        except (BrokerUnavailable, BadMessage):
            return True
        refusers = self._refused_by.get(_needs(pending.spec), set())
        return self._able(status, {*self._barred(), *pending.avoid, *refusers}) > 0

    def _resend(self, job_id: str, pending: _Pending) -> None:
        """Submit the job again, avoiding whom it now avoids. The broker may not have closed
        the lease yet and answer "already pending": look again soon, not after a deadline."""
        still_pending = self._send([self._job(job_id)])
        wait = RECHECK_SECONDS if job_id in still_pending else self.deadline
        pending.deadline = time.monotonic() + wait

    def _run_again(
        self, job_id: str, worker: str, pending: _Pending, reason: str
    ) -> EpisodeResult | None:
        """A log damaged on its way is a lost result, not the job's outcome: the episode is
        deterministic, so run it again (an attempt) rather than score nothing."""
        log.warning("job %s from %s: %s", job_id, worker, reason)
        if pending.attempts >= self.attempts:
            del self._pending[job_id]
            return self._failed(job_id, pending, f"{reason} (attempt {pending.attempts})")
        pending.attempts += 1
        self._resend(job_id, pending)
        return None

    def _failed(
        self,
        job_id: str,
        pending: _Pending,
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


def _matches(result: Result, accepted: Accepted) -> bool:
    """Whether `result` is the one the broker took: its lease, its worker, its very log and the
    scores its worker handed in with it."""
    return (result.lease_id, result.worker, result.digest, result.scores) == (
        accepted.lease_id,
        accepted.worker,
        accepted.digest,
        accepted.scores,
    )


def _needs(spec: EpisodeSpec) -> tuple[str, ...]:
    """The plug-ins a job needs by name: its trajectory kind, then its objectives."""
    return (spec.trajectory.kind, *spec.objectives)


def _lacked_here(spec: EpisodeSpec) -> bool:
    """Whether this process lacks a plug-in the job needs (cannot load it either)."""
    try:
        plugins.load(plugins.TRAJECTORIES, spec.trajectory.kind)
        plugins.load_plugins(plugins.OBJECTIVES, spec.objectives)
    except PluginError:
        return True
    return False
