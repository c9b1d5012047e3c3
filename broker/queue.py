"""The broker's scheduler, as plain Python: jobs in, leases out, no Zenoh and no threads.

Studies queue jobs; free workers ask for work and are handed a lease, or wait ("park") until a
job arrives. One lease per job at a time; a lease expires; a lost worker's lease goes back to the
front of its queue. The first result for a job completes it and every later one is a duplicate.
Among the studies with queued jobs, the next lease goes to the one with the fewest jobs running,
ties to the one served least recently: several studies share the workers evenly.

Waiters are opaque (the Zenoh adapter passes its held queries): methods that can wake a parked
worker return the Assignments for the caller to deliver.
"""

import secrets
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from schemas.wire import Job, Lease, Rejection, StudyState, WorkerState

W = TypeVar("W")

THROUGHPUT_WINDOW = 60.0  # s
# A worker's last result and the loss of its liveliness token travel apart, and the token's loss
# often arrives first (a worker stopped with SIGTERM hands in its job, then leaves): wait this
# long for the result before the job goes to another worker (bench/soak.py counted the reruns).
LOST_WORKER_GRACE = 1.0  # s


class UnknownStudy(KeyError):
    pass


@dataclass
class _Queued:
    study: str
    job: Job


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
    done: int = 0
    last_served: int = 0


@dataclass
class _Worker:
    name: str
    lease: _Lease | None = None
    jobs_done: int = 0


@dataclass(frozen=True)
class Assignment(Generic[W]):
    """Deliver `lease` to the worker that parked `waiter`."""

    waiter: W
    lease: Lease


@dataclass
class Submitted(Generic[W]):
    queued: list[str] = field(default_factory=list)
    already_pending: list[str] = field(default_factory=list)
    rejected: list[Rejection] = field(default_factory=list)
    assignments: list[Assignment[W]] = field(default_factory=list)


class LeaseQueue(Generic[W]):
    def __init__(self, lease_seconds: float = 60.0, clock: Callable[[], float] = time.monotonic):
        self.lease_seconds = lease_seconds
        self._clock = clock
        self._started = clock()
        self._studies: dict[str, _Study] = {}
        self._workers: dict[str, _Worker] = {}
        self._parked: OrderedDict[str, W] = OrderedDict()  # worker name → waiter, oldest first
        self._serial = 0
        self._prefix = secrets.token_hex(3)  # lease ids stay unique across broker restarts
        self._completions: deque[float] = deque()
        self.jobs_done = 0
        self.requeued = 0

    # --- studies ---------------------------------------------------------------------------

    def open_study(self, name: str) -> None:
        self._studies.setdefault(name, _Study(name))

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
        return len(study.queue)

    # --- jobs ------------------------------------------------------------------------------

    def submit(self, study_name: str, jobs: Iterable[Job]) -> Submitted[W]:
        """Queue jobs; a job already queued or running is not queued twice (a resubmission),
        and a job already done is queued again (its result was lost on the way)."""
        study = self._studies.get(study_name)
        if study is None:
            raise UnknownStudy(study_name)
        outcome: Submitted[W] = Submitted()
        for job in jobs:
            if job.job_id in study.queued_ids or job.job_id in study.leased:
                outcome.already_pending.append(job.job_id)
                continue
            study.queue.append(_Queued(study_name, job))
            study.queued_ids.add(job.job_id)
            outcome.queued.append(job.job_id)
        outcome.assignments = self._wake_parked()
        return outcome

    def complete(self, study_name: str, job_id: str, worker_name: str) -> bool:
        """`worker_name` sent a result: True if it is the job's first, False for a duplicate or
        a stray. A late result from an expired lease counts too, and the job need not run again.
        """
        study = self._studies.get(study_name)
        if study is None:
            return False
        lease = study.leased.pop(job_id, None)
        if lease is not None:
            # If the job was leased again, its new worker is still busy with it: that worker is
            # freed when it next asks for work.
            worker = self._workers.get(lease.worker)
            if lease.worker == worker_name and worker is not None and worker.lease is lease:
                worker.lease = None
        elif job_id in study.queued_ids:  # a late result from an expired lease: the job was
            # waiting to be leased again, and need not be
            study.queue.remove(next(item for item in study.queue if item.job.job_id == job_id))
            study.queued_ids.discard(job_id)
        else:
            return False
        study.done += 1
        sender = self._workers.get(worker_name)
        if sender is not None:
            sender.jobs_done += 1
        self.jobs_done += 1
        now = self._clock()
        self._completions.append(now)
        while self._completions[0] < now - THROUGHPUT_WINDOW:
            self._completions.popleft()
        return True

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
            return True
        return False

    def worker_joined(self, name: str) -> None:
        self._workers.setdefault(name, _Worker(name))

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

    def worker_states(self) -> list[WorkerState]:
        return [
            WorkerState(
                name=worker.name,
                busy=worker.lease is not None,
                job=f"{worker.lease.item.study}/{worker.lease.item.job.job_id}"
                if worker.lease
                else "",
                jobs_done=worker.jobs_done,
            )
            for worker in sorted(self._workers.values(), key=lambda worker: worker.name)
        ]

    def study_states(self) -> list[StudyState]:
        return [
            StudyState(
                name=study.name,
                queued=len(study.queue),
                leased=len(study.leased),
                done=study.done,
            )
            for study in sorted(self._studies.values(), key=lambda study: study.name)
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
        if not waiting:
            return None
        study = min(waiting, key=lambda study: (len(study.leased), study.last_served))
        item = study.queue.popleft()
        study.queued_ids.discard(item.job.job_id)
        self._serial += 1
        study.last_served = self._serial
        lease = _Lease(
            f"{self._prefix}-{self._serial}", worker.name, item, self._clock() + self.lease_seconds
        )
        study.leased[item.job.job_id] = lease
        worker.lease = lease
        # The job was validated when it was submitted; skip validating it again on the hot path.
        return Lease.model_construct(
            lease_id=lease.lease_id, study=item.study, job=item.job, expires_in=self.lease_seconds
        )

    def _wake_parked(self) -> list[Assignment[W]]:
        assignments: list[Assignment[W]] = []
        while self._parked:
            worker_name, waiter = next(iter(self._parked.items()))
            worker = self._workers.setdefault(worker_name, _Worker(worker_name))
            lease = self._next_lease(worker)
            if lease is None:
                break
            del self._parked[worker_name]
            assignments.append(Assignment(waiter, lease))
        return assignments

    def _requeue(self, lease: _Lease) -> None:
        """Put a leased job back at the front of its study's queue: it has waited longest."""
        worker = self._workers.get(lease.worker)
        if worker is not None and worker.lease is lease:
            worker.lease = None
        study = self._studies.get(lease.item.study)
        if study is None or study.leased.get(lease.item.job.job_id) is not lease:
            return
        del study.leased[lease.item.job.job_id]
        study.queue.appendleft(lease.item)
        study.queued_ids.add(lease.item.job.job_id)
        self.requeued += 1
