"""The broker's scheduler, as plain Python: jobs in, leases out, no Zenoh and no threads.

Studies queue jobs; free workers ask for a batch of work and are handed leases, or wait ("park")
until a job arrives. One lease per job at a time (but for a copy of an overdue one, below); a lease
expires; a lost worker's leases go back to the front of their queues. A worker gets at most its fair
share of what is queued at once, so a shallow queue is spread over the free workers rather than
taken by the first to ask. A result completes its job only when handed in by the worker a lease of
it named, with the lease's id (random, known to that worker alone); the first such result is the
job's accepted one, and every later one is a duplicate (but the same hand-in again is taken as it
was: a worker retries one whose answer it lost). Among the studies with queued jobs, the next lease
goes to the one with the fewest jobs running, ties to the one served least recently: several studies
share the workers evenly. A job may name workers to avoid (a replica must run elsewhere).

A worker holds at most the batch it was last given. It asks only once done with its batch, handing
in its results with the request; a lease it does not hand in then is one it is not running (its
answer was lost, or it hoards): the job goes back to the front of its queue at once, and the
worker gets no new lease for a pause that doubles with each time it does so again (until it hands
a result in). A lease held much longer than its study's leases usually take (a holder that never
asks again, or a straggler) is overdue: a worker with nothing queued to run gets a copy of its job
under a lease of its own, and the first result handed in under any of the job's leases is its
result (the classic backup task).

Accepted results wait, in the order they were taken, for their study to confirm them by job id
or to collect them by serial: a study pages through them with a cursor, and what it has collected
is forgotten when it next collects. A study's records are numbered within one queue's life (its
`epoch`): a study that collected from another broker, or from this one before a restart, starts
again from the beginning.

Everything the queue remembers is bounded: a worker is remembered while its liveliness token
stands or it holds a lease or a parked request; queues have caps, and submissions a rate; a
study's uncollected results either have a cap that holds back its jobs until it collects, or,
without one, the oldest are forgotten past the queue's cap.

Waiters are opaque (the Zenoh adapter passes its held queries): methods that can wake a parked
worker return the Assignments for the caller to deliver.
"""

import heapq
import math
import secrets
import statistics
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from itertools import islice
from typing import Generic, TypeVar

from gainfarm.schemas.wire import (
    Accepted,
    Job,
    Lease,
    Rejection,
    StudyState,
    WireScores,
    WorkerState,
)

W = TypeVar("W")

THROUGHPUT_WINDOW = 60.0  # s
# A worker's last result and the loss of its liveliness token travel apart, and the token's loss
# often arrives first (a worker stopped with SIGTERM hands in its job, then leaves): wait this
# long for the result before the job goes to another worker (bench/soak.py counted the reruns).
LOST_WORKER_GRACE = 1.0  # s
MAX_LISTED = 200  # workers and studies a status lists by name: it must stay a small message
DEFAULT_MAX_QUEUED = 100_000  # jobs, all studies together (~3 kB each: ~300 MB at most)
DEFAULT_MAX_QUEUED_PER_STUDY = 20_000
RATE_BURST_SECONDS = 10.0  # a rate limit lets this many seconds' worth of jobs through at once
# A worker asking again without handing in its leases gets none for this long, twice as long each
# time it does so again, at most MAX_ABANDON_PAUSE: an honest one does so only when an answer with
# leases was lost (one short pause), a hoarder over and over (it is soon left out).
ABANDON_PAUSE = 2.0  # s
MAX_ABANDON_PAUSE = 300.0  # s
# A lease is overdue once held SPECULATE_FACTOR times the median of its study's last
# TURNAROUND_WINDOW turnarounds (lease to accepted hand-in; the median: a few slow or late holders
# cannot move it), and at least SPECULATE_MIN: then an idle worker may run a copy of its job.
SPECULATE_FACTOR = 3.0
SPECULATE_MIN = 1.0  # s
TURNAROUND_WINDOW = 64
# Accepted records one collect returns (~200 B each): a reply stays far below the message limit.
DEFAULT_COLLECT_LIMIT = 1000


class UnknownStudy(KeyError):
    pass


@dataclass
class _Queued:
    study: str
    job: Job
    leases: "dict[str, _Lease]" = field(default_factory=dict)  # every lease it had, by id


@dataclass
class _Lease:
    lease_id: str
    worker: str
    item: _Queued
    expires: float
    granted: float


@dataclass
class _Study:
    name: str
    queue: deque[_Queued] = field(default_factory=deque)
    queued_ids: set[str] = field(default_factory=set)
    # Each running job's newest lease, by job id, in the order granted (oldest first).
    leased: dict[str, _Lease] = field(default_factory=dict)
    # Results taken and not yet confirmed or collected, by serial: the order they were taken in,
    # which is the order a collecting study pages through them.
    accepted: OrderedDict[int, Accepted] = field(default_factory=OrderedDict)
    serials: dict[str, int] = field(default_factory=dict)  # job id → its record's serial
    last_serial: int = 0
    done: int = 0
    last_served: int = 0
    allowance: float = 0.0  # jobs it may still submit now, under a rate limit
    allowance_at: float = 0.0
    # Seconds from lease to accepted hand-in of its latest results: what "overdue" is measured by.
    turnarounds: deque[float] = field(default_factory=lambda: deque(maxlen=TURNAROUND_WINDOW))


@dataclass
class _Worker:
    name: str
    leases: dict[str, _Lease] = field(default_factory=dict)  # its current batch, by lease id
    jobs_done: int = 0
    alive: bool = False  # its liveliness token stands
    paused_until: float = 0.0  # no new lease before: it asked again without handing its leases in
    abandons: int = 0  # times it did, since it last handed a result in


@dataclass
class _Parked(Generic[W]):
    waiter: W
    want: int  # how many leases it asked for


@dataclass(frozen=True)
class Assignment(Generic[W]):
    """Deliver `leases` (never empty) to the worker that parked `waiter`."""

    waiter: W
    leases: list[Lease]


@dataclass
class Submitted(Generic[W]):
    queued: list[str] = field(default_factory=list)
    already_pending: list[str] = field(default_factory=list)
    deferred: list[str] = field(default_factory=list)
    rejected: list[Rejection] = field(default_factory=list)
    assignments: list[Assignment[W]] = field(default_factory=list)


class LeaseQueue(Generic[W]):
    def __init__(
        self,
        lease_seconds: float = 60.0,
        clock: Callable[[], float] = time.monotonic,
        *,
        max_queued: int = DEFAULT_MAX_QUEUED,
        max_queued_per_study: int = DEFAULT_MAX_QUEUED_PER_STUDY,
        submit_rate: float | None = None,
        max_uncollected_per_study: int | None = None,
    ):
        """`submit_rate`: jobs per second a study may submit (bursts of RATE_BURST_SECONDS'
        worth), or None for no limit. Jobs over a cap or the rate are deferred, not queued.

        `max_uncollected_per_study`: a study holding this many accepted results its analytic
        process has not collected gets no more leases until it collects (a slow study cannot
        make the broker forget its results). None: no hold; past `max_queued_per_study` the
        oldest uncollected result is forgotten instead."""
        self.lease_seconds = lease_seconds
        self.max_queued = max_queued
        self.max_queued_per_study = max_queued_per_study
        self.submit_rate = submit_rate
        self.max_uncollected_per_study = max_uncollected_per_study
        # Serials mean something only within this queue's life: a client that names another
        # epoch (another broker, or this one before a restart) is sent everything again.
        self.epoch = secrets.token_hex(8)
        self._queued_total = 0
        self._clock = clock
        self._started = clock()
        self._studies: dict[str, _Study] = {}
        self._workers: dict[str, _Worker] = {}
        self._parked: OrderedDict[str, _Parked[W]] = OrderedDict()  # by worker, oldest first
        self._serial = 0
        self._completions: deque[float] = deque()
        self.jobs_done = 0
        self.requeued = 0
        self.abandoned = 0  # leases their workers asked past without handing them in
        self.copies = 0  # leases of a job already leased to another worker, overdue

    # --- studies ---------------------------------------------------------------------------

    def open_study(self, name: str) -> None:
        if name not in self._studies:
            self._studies[name] = _Study(name, allowance=self._burst(), allowance_at=self._clock())

    def close_study(self, name: str) -> int:
        """Forget a study whose analytic process is gone; return how many queued jobs it had.

        Its running jobs run out (their workers cannot be told), and their results go unheard.
        """
        study = self._studies.pop(name, None)
        if study is None:
            return 0
        for item in [lease.item for lease in study.leased.values()] + list(study.queue):
            self._release_all(item)
        self._queued_total -= len(study.queue)
        return len(study.queue)

    # --- jobs ------------------------------------------------------------------------------

    def submit(self, study_name: str, jobs: Iterable[Job]) -> Submitted[W]:
        """Queue jobs; a job already queued or running is not queued twice (a resubmission),
        and a job already done is queued again (its result was lost on the way). Jobs past a
        queue's cap or the study's submission rate are deferred: the study submits them later.
        """
        study = self._studies.get(study_name)
        if study is None:
            raise UnknownStudy(study_name)
        outcome: Submitted[W] = Submitted()
        self._refill(study)
        for job in jobs:
            if job.job_id in study.queued_ids or job.job_id in study.leased:
                outcome.already_pending.append(job.job_id)
                continue
            if (
                len(study.queue) >= self.max_queued_per_study
                or self._queued_total >= self.max_queued
                or (self.submit_rate is not None and study.allowance < 1.0)
            ):
                outcome.deferred.append(job.job_id)
                continue
            study.allowance -= 1.0
            study.queue.append(_Queued(study_name, job))
            study.queued_ids.add(job.job_id)
            self._queued_total += 1
            outcome.queued.append(job.job_id)
        outcome.assignments = self._wake_parked()
        return outcome

    def _refill(self, study: _Study) -> None:
        if self.submit_rate is None:
            return
        now = self._clock()
        earned = (now - study.allowance_at) * self.submit_rate
        study.allowance = min(self._burst(), study.allowance + earned)
        study.allowance_at = now

    def _burst(self) -> float:
        """Jobs a study may submit at once: at least one, however slow the rate."""
        return max((self.submit_rate or 0.0) * RATE_BURST_SECONDS, 1.0)

    def complete(
        self,
        study_name: str,
        job_id: str,
        lease_id: str,
        worker_name: str,
        digest: str,
        scores: WireScores | None = None,
    ) -> str | None:
        """`worker_name` hands in a result for `job_id` under `lease_id`: None if it is taken as
        the job's result, else the reason it is refused. Only the worker a lease was handed to
        may hand in under it; a late result from an expired lease counts too (then the job need
        not run again), and after the first every other is a duplicate. The accepted hand-in
        itself, again, is None and counts nothing: its worker lost the answer and retried."""
        study = self._studies.get(study_name)
        if study is None:
            return f"unknown study {study_name!r}"
        lease = study.leased.get(job_id)
        if lease is not None:
            item = lease.item
        elif job_id in study.queued_ids:  # expired and waiting to be leased again
            item = next(item for item in study.queue if item.job.job_id == job_id)
        elif job_id in study.serials:
            taken = study.accepted[study.serials[job_id]]
            if (taken.lease_id, taken.worker, taken.digest) == (lease_id, worker_name, digest):
                return None
            return f"job {job_id!r} is done already"
        else:  # never submitted, or done and confirmed or collected
            return f"no job {job_id!r} waits for a result in study {study_name!r}"
        handed = item.leases.get(lease_id)
        if handed is None:
            return f"lease {lease_id!r} is not one of job {job_id!r}'s"
        if handed.worker != worker_name:
            return f"lease {lease_id!r} was handed to another worker"
        now = self._clock()
        # Every holder of the job is freed: one running a copy hands its result in with its next
        # request, to be refused as a duplicate, and has abandoned nothing.
        self._release_all(item)
        if lease is not None:
            del study.leased[job_id]
        else:
            study.queue.remove(item)
            study.queued_ids.discard(job_id)
            self._queued_total -= 1
        self._store(
            study,
            Accepted(
                job_id=job_id, lease_id=lease_id, worker=worker_name, digest=digest, scores=scores
            ),
        )
        study.done += 1
        study.turnarounds.append(now - handed.granted)
        sender = self._workers.get(worker_name)
        if sender is not None:
            sender.jobs_done += 1
            sender.abandons = 0
        self.jobs_done += 1
        self._completions.append(now)
        while self._completions[0] < now - THROUGHPUT_WINDOW:
            self._completions.popleft()
        return None

    def confirm(self, study_name: str, job_ids: Iterable[str]) -> list[Accepted]:
        """The results taken for these jobs of the study, for those that have one; each is
        then forgotten (its study has been told), so the broker keeps only what is unconfirmed.
        """
        study = self._studies.get(study_name)
        if study is None:
            return []
        confirmed = []
        for job_id in job_ids:
            serial = study.serials.pop(job_id, None)
            if serial is not None:
                confirmed.append(study.accepted.pop(serial))
        return confirmed

    def collect(
        self, study_name: str, epoch: str | None, after: int, limit: int = DEFAULT_COLLECT_LIMIT
    ) -> tuple[list[Accepted], int]:
        """The study's accepted results in the order they were taken, up to `limit` of them,
        and the serial of the last one returned: the cursor to collect after next time.

        Under this queue's `epoch`, the study has every result up to `after`: those are
        forgotten, and the ones after it returned (if none, the cursor stays at `after`). Under
        any other epoch (None, another broker's, or this one's before a restart) the serials
        it knows are not these: it gets the results from the first, and nothing is forgotten.
        """
        study = self._studies.get(study_name)
        if study is None:
            return [], 0
        last = 0
        if epoch == self.epoch:
            # A cursor past the last serial given would forget results not yet taken: a client
            # can only have learnt a serial this queue gave, so anything beyond is clipped.
            last = min(max(after, 0), study.last_serial)
            while study.accepted and next(iter(study.accepted)) <= last:
                _, record = study.accepted.popitem(last=False)
                del study.serials[record.job_id]
        page = list(islice(study.accepted.items(), max(limit, 0)))
        if page:
            last = page[-1][0]
        return [record for _, record in page], last

    # --- workers ---------------------------------------------------------------------------

    def request(
        self, worker_name: str, waiter: W, want: int = 1, wait: bool = True
    ) -> tuple[list[Lease], W | None]:
        """A worker is free and asks for up to `want` jobs: leases now (at most its fair share
        of what is queued; a copy of an overdue job if nothing queued is for it), or none and
        the waiter is parked (unless it wants none, or not to `wait`: e.g. it handed results
        in, whose verdicts it needs now).

        The second value is a waiter this one replaces (the same worker asked again), to be
        answered with "no work". A worker asks only when done with its batch, its results
        handed in (`complete`) just before: the leases it still holds it is not running. Their
        jobs go back to the front of their queues (a late result under them still counts), and
        the worker is paused (`ABANDON_PAUSE`, doubled each time again); the expiry's
        `_wake_parked` hands the jobs on.
        """
        worker = self._workers.setdefault(worker_name, _Worker(worker_name))
        if worker.leases:
            abandoned = list(worker.leases.values())
            worker.leases.clear()
            for lease in reversed(abandoned):  # each to the front: the first ends up first
                self._requeue(lease)
            self.abandoned += len(abandoned)
            pause = min(ABANDON_PAUSE * 2**worker.abandons, MAX_ABANDON_PAUSE)
            worker.abandons += 1
            worker.paused_until = self._clock() + pause
        replaced = self._parked.pop(worker_name, None)
        leases = self._grant(worker, min(want, self._fair_share()) if want > 1 else want)
        if not leases and want > 0 and wait:
            self._parked[worker_name] = _Parked(waiter, want)
        else:
            self._forget_if_idle(worker)
        return leases, replaced.waiter if replaced is not None else None

    def withdraw(self, worker_name: str, waiter: W) -> bool:
        """Stop holding `waiter` (the adapter's hold time is up): True if it was still parked."""
        parked = self._parked.get(worker_name)
        if parked is not None and parked.waiter is waiter:
            del self._parked[worker_name]
            worker = self._workers.get(worker_name)
            if worker is not None:
                self._forget_if_idle(worker)
            return True
        return False

    def worker_joined(self, name: str) -> None:
        self._workers.setdefault(name, _Worker(name)).alive = True

    def worker_lost(self, name: str) -> tuple[list[Assignment[W]], W | None]:
        """A worker died: its jobs go back to the queue once their results have had
        LOST_WORKER_GRACE to arrive (`expire` does it). Also returns its own parked waiter, if
        any, for the adapter to let go of."""
        worker = self._workers.pop(name, None)
        orphan = self._parked.pop(name, None)
        if worker is not None:
            cut = self._clock() + LOST_WORKER_GRACE
            for lease in worker.leases.values():
                lease.expires = min(lease.expires, cut)
        return self._wake_parked(), orphan.waiter if orphan is not None else None

    def expire(self) -> list[Assignment[W]]:
        """Take back every lease past its expiry. Also hands parked workers what has become
        leasable since (e.g. a study below its uncollected cap again after it collected, a job a
        worker gave back, or a copy of an overdue job), and those whose pause is over."""
        now = self._clock()
        for study in list(self._studies.values()):
            expired = [lease for lease in study.leased.values() if lease.expires <= now]
            for lease in reversed(expired):  # each goes to the front: the oldest ends up first
                self._requeue(lease)
        return self._wake_parked()

    # --- reporting -------------------------------------------------------------------------

    def worker_count(self) -> int:
        return len(self._workers)

    def busy(self) -> int:
        return sum(1 for worker in self._workers.values() if worker.leases)

    def study_count(self) -> int:
        return len(self._studies)

    def queued(self) -> int:
        return self._queued_total

    def worker_states(self, limit: int = MAX_LISTED) -> list[WorkerState]:
        """The first `limit` workers by name: a status must stay small however many there are."""
        listed = heapq.nsmallest(limit, self._workers.values(), key=lambda worker: worker.name)
        states = []
        for worker in listed:
            first = next(iter(worker.leases.values()), None)
            states.append(
                WorkerState(
                    name=worker.name,
                    busy=first is not None,
                    job=f"{first.item.study}/{first.item.job.job_id}" if first else "",
                    jobs_done=worker.jobs_done,
                )
            )
        return states

    def study_states(self, limit: int = MAX_LISTED) -> list[StudyState]:
        listed = heapq.nsmallest(limit, self._studies.values(), key=lambda study: study.name)
        return [
            StudyState(
                name=study.name,
                queued=len(study.queue),
                leased=len(study.leased),
                done=study.done,
            )
            for study in listed
        ]

    def uptime(self) -> float:
        return self._clock() - self._started

    def jobs_per_second(self) -> float:
        now = self._clock()
        recent = sum(1 for moment in self._completions if moment >= now - THROUGHPUT_WINDOW)
        return recent / max(min(THROUGHPUT_WINDOW, now - self._started), 1e-9)

    # --- inside ----------------------------------------------------------------------------

    def _fair_share(self) -> int:
        """Leases one worker may take at once: the queue split among the workers that are, or
        will soon be, free, so that a batch leaves none of them idle while it runs."""
        ready = sum(1 for w in self._workers.values() if w.alive or w.name in self._parked)
        return max(1, math.ceil(self._queued_total / max(1, ready)))

    def _grant(
        self, worker: _Worker, count: int, overdue: "list[_Lease] | None" = None
    ) -> list[Lease]:
        """Up to `count` leases, each to the study whose turn it is; if nothing queued is for
        this worker, copies of overdue jobs (`overdue`: as `_overdue` finds them, if known)."""
        if count <= 0 or self._clock() < worker.paused_until:
            return []
        leases: list[Lease] = []
        while len(leases) < count:
            lease = self._next_lease(worker)
            if lease is None:
                break
            leases.append(lease)
        if not leases:
            for late in self._overdue() if overdue is None else overdue:
                item = late.item
                study = self._studies.get(item.study)
                if (
                    study is None
                    or study.leased.get(item.job.job_id) is not late  # copied already
                    or worker.name in item.job.avoid
                    or any(held.worker == worker.name for held in item.leases.values())
                ):
                    continue
                del study.leased[item.job.job_id]  # the copy's lease is the newest
                leases.append(self._lease(study, item, worker))
                self.copies += 1
                if len(leases) == count:
                    break
        return leases

    def _overdue(self) -> "list[_Lease]":
        """Every running job's newest lease held past its study's overdue time, oldest first."""
        now = self._clock()
        cap = self.max_uncollected_per_study
        late: list[_Lease] = []
        for study in self._studies.values():
            if not study.turnarounds or (cap is not None and len(study.accepted) >= cap):
                continue  # nothing known yet of how long its leases take
            limit = max(SPECULATE_MIN, SPECULATE_FACTOR * statistics.median(study.turnarounds))
            for lease in study.leased.values():
                if now - lease.granted < limit:
                    break  # in the order granted: the rest are newer
                late.append(lease)
        late.sort(key=lambda lease: lease.granted)
        return late

    def _next_lease(self, worker: _Worker) -> Lease | None:
        cap = self.max_uncollected_per_study
        waiting = [
            study
            for study in self._studies.values()
            if study.queue and (cap is None or len(study.accepted) < cap)
        ]
        waiting.sort(key=lambda study: (len(study.leased), study.last_served))
        for study in waiting:
            item = next((item for item in study.queue if worker.name not in item.job.avoid), None)
            if item is not None:
                break
        else:
            return None
        study.queue.remove(item)  # the first, unless the first avoids this worker
        study.queued_ids.discard(item.job.job_id)
        self._queued_total -= 1
        return self._lease(study, item, worker)

    def _lease(self, study: _Study, item: _Queued, worker: _Worker) -> Lease:
        """Lease `item` (no longer queued, nor leased in `study.leased`) to `worker`."""
        self._serial += 1
        study.last_served = self._serial
        # Random: a result counts only under its lease's id, which only this worker learns.
        lease_id = secrets.token_urlsafe(16)
        now = self._clock()
        lease = _Lease(lease_id, worker.name, item, now + self.lease_seconds, granted=now)
        item.leases[lease_id] = lease
        study.leased[item.job.job_id] = lease
        worker.leases[lease_id] = lease
        # The job was validated when it was submitted; skip validating it again on the hot path.
        return Lease.model_construct(
            lease_id=lease_id, study=item.study, job=item.job, expires_in=self.lease_seconds
        )

    def _wake_parked(self) -> list[Assignment[W]]:
        """Hand queued jobs to parked workers, oldest parked first, each a batch of up to what
        it asked for; a worker a job avoids is passed over for it."""
        assignments: list[Assignment[W]] = []
        # The share is taken once, of the queue as it stands: each parked worker then gets the
        # same, where a share taken anew after each batch would shrink for the later ones.
        share: int | None = None  # only counted if a batch needs it: it takes a pass
        overdue: list[_Lease] | None = None  # likewise; found once for every parked worker
        for worker_name, parked in list(self._parked.items()):
            if not self._queued_total:
                overdue = self._overdue() if overdue is None else overdue
                if not overdue:
                    break
            count = parked.want
            if count > 1:
                share = self._fair_share() if share is None else share
                count = min(count, share)
            worker = self._workers.setdefault(worker_name, _Worker(worker_name))
            leases = self._grant(worker, count, overdue)
            if leases:
                del self._parked[worker_name]
                assignments.append(Assignment(parked.waiter, leases))
        return assignments

    def _store(self, study: _Study, record: Accepted) -> None:
        """Keep a job's accepted result, as the newest: a job run again replaces its old one."""
        old = study.serials.pop(record.job_id, None)
        if old is not None:
            del study.accepted[old]
        study.last_serial += 1
        study.accepted[study.last_serial] = record
        study.serials[record.job_id] = study.last_serial
        # Under an uncollected cap the study's jobs wait instead: this store stays bounded by
        # the cap plus the leases out when it was reached.
        if self.max_uncollected_per_study is None and (
            len(study.accepted) > self.max_queued_per_study
        ):  # never confirmed nor collected: forget the oldest
            _, oldest = study.accepted.popitem(last=False)
            del study.serials[oldest.job_id]

    def _release(self, lease: _Lease) -> None:
        """The lease's worker no longer holds it (the lease itself may stand, in its study)."""
        worker = self._workers.get(lease.worker)
        if worker is not None and worker.leases.get(lease.lease_id) is lease:
            del worker.leases[lease.lease_id]
            self._forget_if_idle(worker)

    def _release_all(self, item: _Queued) -> None:
        """Free every worker still holding one of the job's leases."""
        for lease in item.leases.values():
            self._release(lease)

    def _forget_if_idle(self, worker: _Worker) -> None:
        """A worker with no token, lease or parked request is forgotten: made-up names asking
        for work cannot fill the broker's memory."""
        if not worker.alive and not worker.leases and worker.name not in self._parked:
            self._workers.pop(worker.name, None)

    def _requeue(self, lease: _Lease) -> None:
        """Put a leased job back at the front of its study's queue: it has waited longest."""
        self._release(lease)
        study = self._studies.get(lease.item.study)
        if study is None or study.leased.get(lease.item.job.job_id) is not lease:
            return
        del study.leased[lease.item.job.job_id]
        study.queue.appendleft(lease.item)
        study.queued_ids.add(lease.item.job.job_id)
        self._queued_total += 1
        self.requeued += 1
