"""The broker's scheduler, as plain Python: jobs in, leases out, no Zenoh and no threads.

Studies queue jobs; free workers ask for work and are handed a lease, or wait ("park") until a
job arrives. One lease per job at a time; a lease expires; a lost worker's lease goes back to the
front of its queue. A result completes its job only when handed in by the worker the lease named,
with the lease's id (random, known to that worker alone); the first such result is the job's
accepted one, the one analytic processes confirm, and every later one is a duplicate. Among the
studies with queued jobs, the next lease goes to the one with the fewest jobs running, ties to the
one served least recently: several studies share the workers evenly. A job may name workers to
avoid (a replica must run elsewhere).

Everything the queue remembers is bounded: a worker is remembered while its liveliness token
stands or it holds a lease or a parked request; queues have caps, and submissions a rate.

Waiters are opaque (the Zenoh adapter passes its held queries): methods that can wake a parked
worker return the Assignments for the caller to deliver.
"""

import heapq
import secrets
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from schemas.wire import Accepted, Job, Lease, Rejection, StudyState, WorkerState

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


class UnknownStudy(KeyError):
    pass


@dataclass
class _Queued:
    study: str
    job: Job
    leases: dict[str, str] = field(default_factory=dict)  # every lease id it had → its worker


@dataclass
class _Lease:
    lease_id: str
    worker: str
    item: _Queued
    expires: float


@dataclass
class _Study:
    name: str
    queue: deque[_Queued] = field(default_factory=deque)
    queued_ids: set[str] = field(default_factory=set)
    leased: dict[str, _Lease] = field(default_factory=dict)  # by job id
    accepted: dict[str, Accepted] = field(default_factory=dict)  # by job id, once done
    done: int = 0
    last_served: int = 0
    allowance: float = 0.0  # jobs it may still submit now, under a rate limit
    allowance_at: float = 0.0


@dataclass
class _Worker:
    name: str
    lease: _Lease | None = None
    jobs_done: int = 0
    alive: bool = False  # its liveliness token stands


@dataclass(frozen=True)
class Assignment(Generic[W]):
    """Deliver `lease` to the worker that parked `waiter`."""

    waiter: W
    lease: Lease


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
    ):
        """`submit_rate`: jobs per second a study may submit (bursts of RATE_BURST_SECONDS'
        worth), or None for no limit. Jobs over a cap or the rate are deferred, not queued."""
        self.lease_seconds = lease_seconds
        self.max_queued = max_queued
        self.max_queued_per_study = max_queued_per_study
        self.submit_rate = submit_rate
        self._queued_total = 0
        self._clock = clock
        self._started = clock()
        self._studies: dict[str, _Study] = {}
        self._workers: dict[str, _Worker] = {}
        self._parked: OrderedDict[str, W] = OrderedDict()  # worker name → waiter, oldest first
        self._serial = 0
        self._completions: deque[float] = deque()
        self.jobs_done = 0
        self.requeued = 0

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
        for lease in study.leased.values():
            worker = self._workers.get(lease.worker)
            if worker is not None and worker.lease is lease:
                worker.lease = None
                self._forget_if_idle(worker)
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
        self, study_name: str, job_id: str, lease_id: str, worker_name: str, digest: str
    ) -> str | None:
        """`worker_name` hands in a result for `job_id` under `lease_id`: None if it is taken as
        the job's result, else the reason it is refused. Only the worker a lease was handed to
        may hand in under it; a late result from an expired lease counts too (then the job need
        not run again), and after the first every other is a duplicate."""
        study = self._studies.get(study_name)
        if study is None:
            return f"unknown study {study_name!r}"
        lease = study.leased.get(job_id)
        if lease is not None:
            item = lease.item
        elif job_id in study.queued_ids:  # expired and waiting to be leased again
            item = next(item for item in study.queue if item.job.job_id == job_id)
        elif job_id in study.accepted:
            return f"job {job_id!r} is done already"
        else:  # never submitted, or done and confirmed
            return f"no job {job_id!r} waits for a result in study {study_name!r}"
        holder = item.leases.get(lease_id)
        if holder is None:
            return f"lease {lease_id!r} is not one of job {job_id!r}'s"
        if holder != worker_name:
            return f"lease {lease_id!r} was handed to another worker"
        if lease is not None:
            del study.leased[job_id]
            # If the job was leased again, its new worker is busy with it (or, if that is this
            # same worker, will be refused its second result): it is freed when it next asks.
            worker = self._workers.get(lease.worker)
            if lease.worker == worker_name and worker is not None and worker.lease is lease:
                worker.lease = None
                self._forget_if_idle(worker)
        else:
            study.queue.remove(item)
            study.queued_ids.discard(job_id)
            self._queued_total -= 1
        study.accepted.pop(job_id, None)  # a job run again: its new result is the newest
        study.accepted[job_id] = Accepted(
            job_id=job_id, lease_id=lease_id, worker=worker_name, digest=digest
        )
        if len(study.accepted) > self.max_queued_per_study:  # never confirmed: forget the oldest
            del study.accepted[next(iter(study.accepted))]
        study.done += 1
        sender = self._workers.get(worker_name)
        if sender is not None:
            sender.jobs_done += 1
        self.jobs_done += 1
        now = self._clock()
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
        return [study.accepted.pop(job_id) for job_id in job_ids if job_id in study.accepted]

    # --- workers ---------------------------------------------------------------------------

    def request(self, worker_name: str, waiter: W) -> tuple[Lease | None, W | None]:
        """A worker is free and asks for work: a lease now, or None and the waiter is parked.

        The second value is a waiter this one replaces (the same worker asked again), to be
        answered with "no work". A worker asks only when free, so it is done with any lease it
        still holds; but that lease's result may still be on its way (it travels on another
        key, and Zenoh does not order the two), so the lease stands until its result or its
        expiry.
        """
        worker = self._workers.setdefault(worker_name, _Worker(worker_name))
        worker.lease = None
        replaced = self._parked.pop(worker_name, None)
        lease = self._next_lease(worker)
        if lease is None:
            self._parked[worker_name] = waiter
        return lease, replaced

    def withdraw(self, worker_name: str, waiter: W) -> bool:
        """Stop holding `waiter` (the adapter's hold time is up): True if it was still parked."""
        if self._parked.get(worker_name) is waiter:
            del self._parked[worker_name]
            worker = self._workers.get(worker_name)
            if worker is not None:
                self._forget_if_idle(worker)
            return True
        return False

    def worker_joined(self, name: str) -> None:
        self._workers.setdefault(name, _Worker(name)).alive = True

    def worker_lost(self, name: str) -> tuple[list[Assignment[W]], W | None]:
        """A worker died: its job goes back to the queue once its result has had
        LOST_WORKER_GRACE to arrive (`expire` does it). Also returns its own parked waiter, if
        any, for the adapter to let go of."""
        worker = self._workers.pop(name, None)
        orphan = self._parked.pop(name, None)
        if worker is not None and worker.lease is not None:
            lease = worker.lease
            lease.expires = min(lease.expires, self._clock() + LOST_WORKER_GRACE)
        return self._wake_parked(), orphan

    def expire(self) -> list[Assignment[W]]:
        """Take back every lease past its expiry."""
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
        return sum(1 for worker in self._workers.values() if worker.lease is not None)

    def study_count(self) -> int:
        return len(self._studies)

    def queued(self) -> int:
        return self._queued_total

    def worker_states(self, limit: int = MAX_LISTED) -> list[WorkerState]:
        """The first `limit` workers by name: a status must stay small however many there are."""
        listed = heapq.nsmallest(limit, self._workers.values(), key=lambda worker: worker.name)
        return [
            WorkerState(
                name=worker.name,
                busy=worker.lease is not None,
                job=f"{worker.lease.item.study}/{worker.lease.item.job.job_id}"
                if worker.lease
                else "",
                jobs_done=worker.jobs_done,
            )
            for worker in listed
        ]

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

    def _next_lease(self, worker: _Worker) -> Lease | None:
        waiting = [study for study in self._studies.values() if study.queue]
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
        self._serial += 1
        study.last_served = self._serial
        # Random: a result counts only under its lease's id, which only this worker learns.
        lease_id = secrets.token_urlsafe(16)
        item.leases[lease_id] = worker.name
        lease = _Lease(lease_id, worker.name, item, self._clock() + self.lease_seconds)
        study.leased[item.job.job_id] = lease
        worker.lease = lease
        # The job was validated when it was submitted; skip validating it again on the hot path.
        return Lease.model_construct(
            lease_id=lease_id, study=item.study, job=item.job, expires_in=self.lease_seconds
        )

    def _wake_parked(self) -> list[Assignment[W]]:
        """Hand queued jobs to parked workers, oldest parked first; a worker a job avoids is
        passed over for it."""
        assignments: list[Assignment[W]] = []
        for worker_name in list(self._parked):
            if not any(study.queue for study in self._studies.values()):
                break
            worker = self._workers.setdefault(worker_name, _Worker(worker_name))
            lease = self._next_lease(worker)
            if lease is not None:
                waiter = self._parked.pop(worker_name)
                assignments.append(Assignment(waiter, lease))
        return assignments

    def _forget_if_idle(self, worker: _Worker) -> None:
        """A worker with no token, lease or parked request is forgotten: made-up names asking
        for work cannot fill the broker's memory."""
        if not worker.alive and worker.lease is None and worker.name not in self._parked:
            self._workers.pop(worker.name, None)

    def _requeue(self, lease: _Lease) -> None:
        """Put a leased job back at the front of its study's queue: it has waited longest."""
        worker = self._workers.get(lease.worker)
        if worker is not None and worker.lease is lease:
            worker.lease = None
            self._forget_if_idle(worker)
        study = self._studies.get(lease.item.study)
        if study is None or study.leased.get(lease.item.job.job_id) is not lease:
            return
        del study.leased[lease.item.job.job_id]
        study.queue.appendleft(lease.item)
        study.queued_ids.add(lease.item.job.job_id)
        self._queued_total += 1
        self.requeued += 1
