"""The broker's scheduling core, LeaseQueue: pure Python on a fake clock, no Zenoh, no threads."""

import hashlib
import math
from collections import Counter
from dataclasses import dataclass

import pytest

from gainfarm.broker.queue import (
    ABANDON_PAUSE,
    DEFAULT_MAX_QUEUED,
    DEFAULT_MAX_QUEUED_PER_STUDY,
    LOST_WORKER_GRACE,
    MAX_ABANDON_PAUSE,
    MAX_LISTED,
    RATE_BURST_SECONDS,
    SPECULATE_FACTOR,
    THROUGHPUT_WINDOW,
    Assignment,
    LeaseQueue,
    UnknownStudy,
)
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.wire import MAX_BATCH, Accepted, Job, Lease, StudyState, WorkerState
from tests.helpers import open_studies

EPISODE = EpisodeSpec(gains=PDGains(kp=(100.0,) * 7, kd=(10.0,) * 7))
LEASE_SECONDS = 10.0


class FakeClock:
    def __init__(self, now: float = 1000.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


@dataclass(eq=False)  # compared by identity, like the adapter's held queries
class Waiter:
    worker: str


Queue = LeaseQueue[Waiter]


def make_queue(
    *studies: str,
    lease_seconds: float = LEASE_SECONDS,
    max_queued: int = DEFAULT_MAX_QUEUED,
    max_queued_per_study: int = DEFAULT_MAX_QUEUED_PER_STUDY,
    submit_rate: float | None = None,
    max_uncollected_per_study: int | None = None,
) -> tuple[Queue, FakeClock]:
    clock = FakeClock()
    queue: Queue = LeaseQueue(
        lease_seconds=lease_seconds,
        clock=clock,
        max_queued=max_queued,
        max_queued_per_study=max_queued_per_study,
        submit_rate=submit_rate,
        max_uncollected_per_study=max_uncollected_per_study,
    )
    for study in studies:
        queue.open_study(study)
    return queue, clock


def jobs(*job_ids: str, avoid: tuple[str, ...] = ()) -> list[Job]:
    return [Job(job_id=job_id, spec=EPISODE, avoid=list(avoid)) for job_id in job_ids]


def digest_of(text: str) -> str:
    """A SHA-256 hex digest, as a worker computes of its episode log."""
    return hashlib.sha256(text.encode()).hexdigest()


DIGEST = digest_of("an episode log")


def ask(queue: Queue, worker: str, waiter: Waiter) -> tuple[Lease | None, Waiter | None]:
    """`worker` asks for one job, as the broker's adapter does: the lease it gets at once, if
    any, and the waiter its request replaces."""
    leases, replaced = queue.request(worker, waiter)
    assert len(leases) <= 1
    return (leases[0] if leases else None), replaced


def take(queue: Queue, worker: str) -> Lease:
    """`worker` (a real one: its liveliness token stands) asks for work and must get a lease
    straight away."""
    queue.worker_joined(worker)
    lease, replaced = ask(queue, worker, Waiter(worker))
    assert lease is not None, f"{worker} got no lease"
    assert replaced is None
    return lease


def park(queue: Queue, worker: str) -> Waiter:
    """`worker` (a real one: its liveliness token stands) asks for work and must be parked."""
    queue.worker_joined(worker)
    waiter = Waiter(worker)
    lease, replaced = ask(queue, worker, waiter)
    assert lease is None, f"{worker} got {lease}"
    assert replaced is None
    return waiter


def hand_in(queue: Queue, lease: Lease, worker: str, digest: str = DIGEST) -> str | None:
    """`worker` hands in a result for `lease`'s job under `lease`'s id: None if it is taken."""
    return queue.complete(lease.study, lease.job.job_id, lease.lease_id, worker, digest)


def refused(reason: str | None, mentioning: str) -> bool:
    """A result was turned away, with a reason that names what was wrong."""
    return isinstance(reason, str) and mentioning in reason


def assert_counts_add_up(queue: Queue) -> None:
    """The totals agree with the per-study and per-worker records, whatever the listing limit."""
    studies = queue.study_states(limit=queue.study_count() + 1)
    assert len(studies) == queue.study_count()
    assert sum(s.queued for s in studies) == queue.queued() >= 0
    assert len(queue.worker_states(limit=queue.worker_count() + 1)) == queue.worker_count()


def state(queue: Queue, study: str) -> StudyState:
    (found,) = [s for s in queue.study_states() if s.name == study]
    return found


def worker(queue: Queue, name: str) -> WorkerState:
    (found,) = [w for w in queue.worker_states() if w.name == name]
    return found


def job_ids_in_lease_order(queue: Queue, count: int) -> list[str]:
    """Lease `count` jobs, one worker each, and return their ids in the order handed out."""
    return [take(queue, f"drain-{index}").job.job_id for index in range(count)]


# --- studies and submission --------------------------------------------------------------------


def test_submit_to_unknown_study_raises() -> None:
    queue, _ = make_queue("s")
    with pytest.raises(UnknownStudy) as raised:
        queue.submit("nope", jobs("j1"))
    assert isinstance(raised.value, KeyError)
    assert raised.value.args == ("nope",)
    with pytest.raises(UnknownStudy):
        queue.submit("nope", [])
    assert [s.name for s in queue.study_states()] == ["s"]


def test_open_study_is_idempotent_and_keeps_its_queue() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    queue.open_study("s")
    assert open_studies(queue) == {"s"}
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=0, done=0)


def test_submit_reports_what_was_queued() -> None:
    queue, _ = make_queue("s")
    submitted = queue.submit("s", jobs("j1", "j2", "j3"))
    assert submitted.queued == ["j1", "j2", "j3"]
    assert submitted.already_pending == []
    assert submitted.rejected == []
    assert submitted.assignments == []
    assert state(queue, "s") == StudyState(name="s", queued=3, leased=0, done=0)


def test_jobs_are_leased_first_in_first_out_within_a_study() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3"))
    queue.submit("s", jobs("j4", "j5"))
    assert job_ids_in_lease_order(queue, 5) == ["j1", "j2", "j3", "j4", "j5"]
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=5, done=0)


# --- requesting, parking, withdrawing ----------------------------------------------------------


def test_request_returns_a_lease_at_once_when_work_is_queued() -> None:
    queue, _ = make_queue("s", lease_seconds=42.0)
    queue.submit("s", jobs("j1"))
    lease, replaced = ask(queue, "w1", Waiter("w1"))
    assert replaced is None
    assert lease is not None
    assert lease.study == "s"
    assert lease.job == jobs("j1")[0]
    assert lease.expires_in == 42.0
    assert lease.lease_id
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=1, done=0)
    assert worker(queue, "w1") == WorkerState(name="w1", busy=True, job="s/j1", jobs_done=0)


def test_request_without_work_parks_and_a_later_submit_assigns_to_the_waiter() -> None:
    queue, _ = make_queue("s")
    waiter = park(queue, "w1")
    assert worker(queue, "w1").busy is False

    submitted = queue.submit("s", jobs("j1"))

    assert submitted.queued == ["j1"]
    assert len(submitted.assignments) == 1
    (assignment,) = submitted.assignments
    assert isinstance(assignment, Assignment)
    assert assignment.waiter is waiter
    assert assignment.leases[0].study == "s"
    assert assignment.leases[0].job.job_id == "j1"
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=1, done=0)
    assert worker(queue, "w1") == WorkerState(name="w1", busy=True, job="s/j1", jobs_done=0)
    # No longer parked: it cannot be withdrawn, and another job goes unassigned.
    assert queue.withdraw("w1", waiter) is False
    assert queue.submit("s", jobs("j2")).assignments == []
    assert state(queue, "s").queued == 1


def test_parked_workers_are_served_oldest_first_and_only_while_work_lasts() -> None:
    queue, _ = make_queue("s")
    first, second, third = park(queue, "w1"), park(queue, "w2"), park(queue, "w3")

    one = queue.submit("s", jobs("j1"))
    assert [(a.waiter, a.leases[0].job.job_id) for a in one.assignments] == [(first, "j1")]

    two = queue.submit("s", jobs("j2", "j3", "j4"))
    assert [(a.waiter, a.leases[0].job.job_id) for a in two.assignments] == [
        (second, "j2"),
        (third, "j3"),
    ]
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=3, done=0)


def test_a_second_request_from_the_same_worker_replaces_its_parked_waiter() -> None:
    queue, _ = make_queue("s")
    old = park(queue, "w1")
    new = Waiter("w1")

    lease, replaced = ask(queue, "w1", new)

    assert lease is None
    assert replaced is old
    assert queue.withdraw("w1", old) is False  # the old one is no longer held
    submitted = queue.submit("s", jobs("j1", "j2"))
    assert [a.waiter for a in submitted.assignments] == [new]
    assert state(queue, "s").queued == 1


def test_withdraw_releases_only_the_parked_waiter() -> None:
    queue, _ = make_queue("s")
    waiter = park(queue, "w1")

    assert queue.withdraw("w1", Waiter("w1")) is False  # another waiter: not the parked one
    assert queue.withdraw("w2", waiter) is False  # not parked under that name
    assert queue.withdraw("w1", waiter) is True
    assert queue.withdraw("w1", waiter) is False  # already let go

    submitted = queue.submit("s", jobs("j1"))
    assert submitted.assignments == []
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=0)


def test_one_lease_per_job_at_a_time() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1"))
    first = take(queue, "w1")
    assert first.job.job_id == "j1"

    waiter = park(queue, "w2")  # the only job is leased: nothing for w2
    assert queue.submit("s", jobs("j1")).assignments == []  # resubmitting it changes nothing
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=1, done=0)
    assert queue.withdraw("w2", waiter) is True


def test_lease_ids_are_unique() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs(*(f"j{n}" for n in range(50))))
    ids = [take(queue, f"w{n}").lease_id for n in range(50)]
    assert len(set(ids)) == 50


# --- expiry ------------------------------------------------------------------------------------


def test_a_lease_expires_after_lease_seconds_and_its_job_goes_to_the_front() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3"))
    lease = take(queue, "w1")
    assert lease.job.job_id == "j1"

    clock.advance(LEASE_SECONDS - 0.001)
    assert queue.expire() == []
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=1, done=0)
    assert queue.requeued == 0
    assert worker(queue, "w1").busy is True

    clock.advance(0.001)  # exactly at expiry
    assert queue.expire() == []  # nobody parked to hand it to
    assert state(queue, "s") == StudyState(name="s", queued=3, leased=0, done=0)
    assert queue.requeued == 1
    assert worker(queue, "w1") == WorkerState(name="w1", busy=False, job="", jobs_done=0)

    again = take(queue, "w2")
    assert again.job.job_id == "j1"  # front of the queue, ahead of j2 and j3
    assert again.lease_id != lease.lease_id
    assert job_ids_in_lease_order(queue, 2) == ["j2", "j3"]


def test_expire_hands_the_expired_job_to_a_parked_waiter() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    old = take(queue, "w1")
    waiter = park(queue, "w2")

    clock.advance(LEASE_SECONDS)
    assignments = queue.expire()

    assert len(assignments) == 1
    assert assignments[0].waiter is waiter
    assert assignments[0].leases[0].job.job_id == "j1"
    assert assignments[0].leases[0].lease_id != old.lease_id
    assert queue.requeued == 1
    assert worker(queue, "w1").busy is False
    assert worker(queue, "w2") == WorkerState(name="w2", busy=True, job="s/j1", jobs_done=0)
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=1, done=0)


def test_a_re_leased_job_gets_a_fresh_expiry() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()
    take(queue, "w2")  # leased again at t0 + LEASE_SECONDS

    clock.advance(LEASE_SECONDS - 0.001)
    assert queue.expire() == []
    assert state(queue, "s").leased == 1
    assert queue.requeued == 1
    clock.advance(0.001)
    queue.expire()
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=0)
    assert queue.requeued == 2


def test_expire_only_takes_back_leases_past_their_expiry() -> None:
    queue, clock = make_queue("a", "b")
    queue.submit("a", jobs("a1"))
    take(queue, "w1")
    clock.advance(5.0)
    queue.submit("b", jobs("b1"))
    take(queue, "w2")

    clock.advance(LEASE_SECONDS - 5.0)  # a1 is due, b1 has 5 s left
    queue.expire()
    assert state(queue, "a") == StudyState(name="a", queued=1, leased=0, done=0)
    assert state(queue, "b") == StudyState(name="b", queued=0, leased=1, done=0)
    assert [w.busy for w in queue.worker_states()] == [False, True]


def test_jobs_expiring_together_go_back_in_their_original_order() -> None:
    """Each requeued job has waited longer than everything behind it, so several jobs taken back
    at once must keep their order: the oldest first."""
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3"))
    take(queue, "w1")  # j1
    clock.advance(1.0)
    take(queue, "w2")  # j2

    clock.advance(LEASE_SECONDS)  # both are past their expiry
    queue.expire()

    assert queue.requeued == 2
    assert job_ids_in_lease_order(queue, 3) == ["j1", "j2", "j3"]


# --- lost and abandoning workers ---------------------------------------------------------------


def test_a_lost_worker_s_job_goes_back_to_the_front_of_its_queue_after_a_grace() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3"))
    take(queue, "w1")  # j1

    assignments, orphan = queue.worker_lost("w1")

    assert assignments == []
    assert orphan is None
    assert [w.name for w in queue.worker_states()] == []
    # Its result may still be on the way: the job waits for it a moment, not a whole lease.
    assert queue.expire() == [] and queue.requeued == 0
    clock.advance(LOST_WORKER_GRACE)
    assert queue.expire() == []
    assert queue.requeued == 1
    assert job_ids_in_lease_order(queue, 3) == ["j1", "j2", "j3"]


def test_a_lost_worker_s_job_goes_straight_to_a_parked_worker() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    waiter = park(queue, "w2")

    assert queue.worker_lost("w1") == ([], None)
    clock.advance(LOST_WORKER_GRACE)
    assignments = queue.expire()

    assert [(a.waiter, a.leases[0].job.job_id) for a in assignments] == [(waiter, "j1")]
    assert queue.worker_states() == [WorkerState(name="w2", busy=True, job="s/j1", jobs_done=0)]


def test_a_lost_parked_worker_returns_its_orphaned_waiter() -> None:
    queue, _ = make_queue("s")
    waiter = park(queue, "w1")

    assignments, orphan = queue.worker_lost("w1")

    assert assignments == []
    assert orphan is waiter
    assert queue.withdraw("w1", waiter) is False
    submitted = queue.submit("s", jobs("j1"))
    assert submitted.assignments == []  # nobody left to hand it to
    assert state(queue, "s").queued == 1
    assert queue.requeued == 0


def test_losing_an_unknown_worker_changes_nothing() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1"))
    assert queue.worker_lost("ghost") == ([], None)
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=0)
    assert queue.requeued == 0


def test_a_worker_asking_again_without_handing_in_gives_its_leases_back_and_waits() -> None:
    """Results are handed in with the next request: a lease not handed in then is not being
    run (a hoarder's, or one whose answer was lost). Its job goes back to the front at once, and
    the worker gets nothing new for a pause, longer each time it does so again."""
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3"))
    first = take(queue, "w1")
    assert first.job.job_id == "j1"

    waiter = park(queue, "w1")  # asks again; j1 not handed in

    assert (queue.requeued, queue.abandoned) == (1, 1)
    assert state(queue, "s") == StudyState(name="s", queued=3, leased=0, done=0)
    assert worker(queue, "w1") == WorkerState(name="w1", busy=False, job="", jobs_done=0)
    assert take(queue, "w2").job.job_id == "j1"  # back at the front, for another worker
    clock.advance(ABANDON_PAUSE - 0.1)
    assert queue.expire() == []  # still paused
    clock.advance(0.1)
    (woken,) = queue.expire()
    assert woken.waiter is waiter and woken.leases[0].job.job_id == "j2"

    waiter = park(queue, "w1")  # again: twice the pause
    clock.advance(2 * ABANDON_PAUSE - 0.1)
    assert queue.expire() == []
    clock.advance(0.1)
    (woken,) = queue.expire()
    assert woken.waiter is waiter and woken.leases[0].job.job_id == "j2"
    assert hand_in(queue, woken.leases[0], "w1") is None  # a result handed in: the pause resets
    assert hand_in(queue, first, "w1") is None  # and a late one under the given-back lease counts
    assert take(queue, "w1").job.job_id == "j3"
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=1, done=2)
    assert not worker(queue, "w2").busy  # j1 is done: w2's copy of it will be a duplicate
    assert_counts_add_up(queue)


def test_a_hoarder_holds_one_batch_and_is_soon_left_out() -> None:
    """A worker that asks again and again, never handing anything in, holds at most the batch it
    was last given, and its pauses double up to MAX_ABANDON_PAUSE."""
    queue, clock = make_queue("s", lease_seconds=1e9)
    queue.submit("s", jobs(*(f"j{n}" for n in range(100))))
    queue.worker_joined("hoarder")
    grants = 0
    for _ in range(2_000):  # about an hour of asking, once a second
        leases, _ = queue.request("hoarder", Waiter("hoarder"), want=MAX_BATCH)
        grants += bool(leases)
        assert state(queue, "s").leased <= MAX_BATCH
        clock.advance(1.0)
    assert MAX_ABANDON_PAUSE < 2_000
    assert grants <= math.log2(MAX_ABANDON_PAUSE / ABANDON_PAUSE) + 2_000 / MAX_ABANDON_PAUSE + 2
    assert state(queue, "s").queued + state(queue, "s").leased == 100


# --- results -----------------------------------------------------------------------------------


def test_only_the_first_result_for_a_job_counts() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    lease = take(queue, "w1")
    clock.advance(1.0)

    assert hand_in(queue, lease, "w1") is None
    assert refused(hand_in(queue, lease, "w1", digest_of("another")), "j1")  # duplicate
    stray = queue.complete("s", "nope", lease.lease_id, "w1", DIGEST)  # never submitted
    assert refused(stray, "nope")
    unknown = queue.complete("other", "j1", lease.lease_id, "w1", DIGEST)  # unknown study
    assert refused(unknown, "other")
    assert queue.confirm("s", ["j1"])[0].digest == DIGEST  # the first one's

    assert queue.jobs_done == 1
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=1)
    assert worker(queue, "w1") == WorkerState(name="w1", busy=False, job="", jobs_done=1)


def test_a_result_for_a_closed_study_is_not_counted() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1"))
    lease = take(queue, "w1")
    queue.close_study("s")

    assert refused(hand_in(queue, lease, "w1"), "s")
    assert queue.jobs_done == 0
    assert worker(queue, "w1").jobs_done == 0

    queue.open_study("s")  # reopened under the same name: a fresh study
    assert refused(hand_in(queue, lease, "w1"), "j1")
    assert queue.confirm("s", ["j1"]) == []
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=0)


def test_a_late_result_for_an_expired_and_requeued_job_completes_it() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    first = take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=0, done=0)

    assert hand_in(queue, first, "w1") is None  # w1 was slow, not dead
    assert_counts_add_up(queue)

    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=1)
    assert queue.jobs_done == 1
    assert take(queue, "w2").job.job_id == "j2"
    park(queue, "w3")  # j1 is not leased again
    assert refused(hand_in(queue, first, "w1", digest_of("another")), "j1")


def test_a_late_result_for_an_expired_and_re_leased_job_completes_it_once() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    first = take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()
    second = take(queue, "w2")  # j1 again

    assert hand_in(queue, first, "w1") is None  # w1's late result, under its own lease's id
    # w1 gets the credit; w2 is freed of the job (its result will be a duplicate).
    assert worker(queue, "w1") == WorkerState(name="w1", busy=False, job="", jobs_done=1)
    assert worker(queue, "w2") == WorkerState(name="w2", busy=False, job="", jobs_done=0)
    assert refused(hand_in(queue, second, "w2"), "j1")  # w2's result, a duplicate
    assert queue.jobs_done == 1
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=1)
    park(queue, "w2")  # it abandoned nothing: parked, and the done job is not requeued
    assert (queue.abandoned, state(queue, "s").queued) == (0, 0)
    assert queue.requeued == 1


def test_a_result_overtaken_by_its_worker_s_departure_still_completes_the_job() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    lease = take(queue, "w1")
    waiter = park(queue, "w2")
    queue.worker_lost("w1")  # a worker stopped with SIGTERM: its token's loss came first
    clock.advance(LOST_WORKER_GRACE / 2)

    assert hand_in(queue, lease, "w1") is None
    clock.advance(LOST_WORKER_GRACE)
    assert queue.expire() == []  # nothing to run twice
    assert queue.requeued == 0 and queue.withdraw("w2", waiter) is True


def test_a_result_after_the_worker_was_lost_completes_the_requeued_job() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    lease = take(queue, "w1")
    queue.worker_lost("w1")
    clock.advance(LOST_WORKER_GRACE)
    queue.expire()
    assert state(queue, "s").queued == 1

    assert hand_in(queue, lease, "w1") is None
    assert queue.queued() == 0
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=1)
    park(queue, "w2")


# --- resubmission ------------------------------------------------------------------------------


def test_resubmitting_a_queued_or_leased_job_reports_it_already_pending() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    take(queue, "w1")  # j1 leased, j2 queued

    submitted = queue.submit("s", jobs("j1", "j2", "j3"))

    assert submitted.queued == ["j3"]
    assert submitted.already_pending == ["j1", "j2"]
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=1, done=0)
    assert job_ids_in_lease_order(queue, 2) == ["j2", "j3"]


def test_a_job_twice_in_one_submission_is_queued_once() -> None:
    queue, _ = make_queue("s")
    submitted = queue.submit("s", jobs("j1", "j1"))
    assert submitted.queued == ["j1"]
    assert submitted.already_pending == ["j1"]
    assert state(queue, "s").queued == 1


def test_resubmitting_a_done_job_queues_it_again() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1"))
    first = take(queue, "w1")
    assert hand_in(queue, first, "w1") is None

    submitted = queue.submit("s", jobs("j1"))

    assert submitted.queued == ["j1"]
    assert submitted.already_pending == []
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=1)
    again = take(queue, "w1")
    assert again.job.job_id == "j1"
    assert refused(hand_in(queue, first, "w1"), first.lease_id)  # the old run's lease is over
    assert hand_in(queue, again, "w1") is None  # its new result counts
    assert queue.jobs_done == 2


def test_the_same_job_id_in_two_studies_is_two_jobs() -> None:
    queue, _ = make_queue("a", "b")
    assert queue.submit("a", jobs("j1")).queued == ["j1"]
    assert queue.submit("b", jobs("j1")).queued == ["j1"]
    in_a, in_b = take(queue, "w1"), take(queue, "w2")
    assert (in_a.study, in_b.study) == ("a", "b")
    # a's lease is not b's: the same job id in another study is another job
    assert refused(queue.complete("b", "j1", in_a.lease_id, "w1", DIGEST), in_a.lease_id)
    assert hand_in(queue, in_a, "w1") is None
    assert hand_in(queue, in_b, "w2") is None
    assert [s.done for s in queue.study_states()] == [1, 1]


# --- closing studies ---------------------------------------------------------------------------


def test_close_study_drops_its_queue_and_frees_its_workers() -> None:
    queue, _ = make_queue("s", "t")
    queue.submit("s", jobs("s1", "s2", "s3", "s4", "s5"))
    take(queue, "w1")  # s1
    take(queue, "w2")  # s2
    queue.submit("t", jobs("t1"))
    take(queue, "w3")  # t1

    assert queue.close_study("s") == 3

    assert "s" not in open_studies(queue)
    assert [s.name for s in queue.study_states()] == ["t"]
    assert queue.worker_states() == [
        WorkerState(name="w1", busy=False, job="", jobs_done=0),
        WorkerState(name="w2", busy=False, job="", jobs_done=0),
        WorkerState(name="w3", busy=True, job="t/t1", jobs_done=0),
    ]
    with pytest.raises(UnknownStudy):
        queue.submit("s", jobs("s6"))
    # A freed worker asking again, with no work anywhere, is parked.
    park(queue, "w1")
    assert queue.requeued == 0
    assert state(queue, "t") == StudyState(name="t", queued=0, leased=1, done=0)


def test_closing_an_unknown_or_empty_study_drops_nothing() -> None:
    queue, _ = make_queue("s")
    assert queue.close_study("nope") == 0
    assert queue.close_study("s") == 0
    assert queue.close_study("s") == 0  # twice
    assert queue.study_states() == []


def test_a_closed_study_s_leases_do_not_come_back_on_expiry() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    queue.close_study("s")
    queue.open_study("s")
    waiter = park(queue, "w2")

    clock.advance(LEASE_SECONDS)
    assert queue.expire() == []
    assert queue.requeued == 0
    assert queue.withdraw("w2", waiter) is True


# --- fairness ----------------------------------------------------------------------------------


def test_two_studies_share_the_workers_evenly() -> None:
    queue, _ = make_queue("a", "b")
    queue.submit("a", jobs(*(f"a{n}" for n in range(40))))
    queue.submit("b", jobs(*(f"b{n}" for n in range(40))))
    workers = [f"w{n}" for n in range(4)]

    handed: list[str] = []
    leases: dict[str, Lease] = {}
    for name in workers:
        leases[name] = take(queue, name)
        handed.append(leases[name].study)
    for _ in range(8):
        for name in workers:
            held = leases[name]
            assert worker(queue, name).job == f"{held.study}/{held.job.job_id}"
            assert hand_in(queue, held, name) is None
            leases[name] = take(queue, name)
            handed.append(leases[name].study)
            running = Counter(w.job.split("/")[0] for w in queue.worker_states() if w.busy)
            assert running == {"a": 2, "b": 2}

    assert handed == ["a", "b"] * 18  # strict alternation
    assert Counter(handed) == {"a": 18, "b": 18}
    assert state(queue, "a") == StudyState(name="a", queued=22, leased=2, done=16)
    assert state(queue, "b") == StudyState(name="b", queued=22, leased=2, done=16)


def test_the_study_with_fewer_running_leases_is_preferred() -> None:
    queue, _ = make_queue("a", "b")
    queue.submit("a", jobs(*(f"a{n}" for n in range(10))))
    for name in ("w1", "w2", "w3"):
        assert take(queue, name).study == "a"  # alone, a takes every worker

    queue.submit("b", jobs(*(f"b{n}" for n in range(10))))
    # b is served until it runs as many jobs as a, though a's jobs have waited longer.
    assert [take(queue, name).study for name in ("w4", "w5", "w6")] == ["b", "b", "b"]
    # Tied at 3 each: the study served least recently (a) goes next, then they alternate.
    assert [take(queue, name).study for name in ("w7", "w8", "w9", "w10")] == ["a", "b", "a", "b"]


def test_a_study_that_completes_faster_gets_the_next_worker() -> None:
    queue, _ = make_queue("a", "b")
    queue.submit("a", jobs(*(f"a{n}" for n in range(10))))
    queue.submit("b", jobs(*(f"b{n}" for n in range(10))))
    leases = {name: take(queue, name) for name in ("w1", "w2", "w3", "w4")}
    assert [lease.study for lease in leases.values()] == ["a", "b", "a", "b"]

    # Both of b's jobs finish; a still runs two, so the next two workers both go to b.
    assert hand_in(queue, leases["w2"], "w2") is None
    assert hand_in(queue, leases["w4"], "w4") is None
    assert [take(queue, name).study for name in ("w2", "w4")] == ["b", "b"]


def test_expire_wakes_parked_workers_fairly_across_studies() -> None:
    queue, clock = make_queue("a", "b")
    queue.submit("a", jobs("a1", "a2", "a3"))
    for name in ("w1", "w2", "w3"):
        take(queue, name)
    queue.submit("b", jobs("b1"))
    take(queue, "w4")
    waiters = [park(queue, name) for name in ("p1", "p2", "p3")]

    clock.advance(LEASE_SECONDS)
    assignments = queue.expire()  # both studies have their jobs back, none running

    assert [a.waiter for a in assignments] == waiters
    # a and b run none: a was served least recently. Then b runs fewer. Then tied, a again.
    # (Which of a's jobs goes first is test_jobs_expiring_together_go_back_in_their_original_order.)
    assert [a.leases[0].study for a in assignments] == ["a", "b", "a"]
    assert state(queue, "a") == StudyState(name="a", queued=1, leased=2, done=0)
    assert state(queue, "b") == StudyState(name="b", queued=0, leased=1, done=0)


# --- reporting ---------------------------------------------------------------------------------


def test_worker_and_study_states_report_the_farm() -> None:
    queue, _ = make_queue("beta", "alpha")
    queue.worker_joined("zed")
    queue.worker_joined("zed")  # twice: still one worker
    assert queue.worker_states() == [WorkerState(name="zed", busy=False, job="", jobs_done=0)]
    queue.submit("alpha", jobs("a1", "a2", "a3"))
    a1 = take(queue, "w1")
    assert a1.job.job_id == "a1"
    queue.submit("beta", jobs("b1"))
    assert take(queue, "w2").job.job_id == "b1"  # beta runs fewer
    assert hand_in(queue, a1, "w1") is None
    assert take(queue, "w1").job.job_id == "a2"  # beta has nothing queued

    assert queue.worker_states() == [  # by name
        WorkerState(name="w1", busy=True, job="alpha/a2", jobs_done=1),
        WorkerState(name="w2", busy=True, job="beta/b1", jobs_done=0),
        WorkerState(name="zed", busy=False, job="", jobs_done=0),
    ]
    assert queue.study_states() == [  # by name
        StudyState(name="alpha", queued=1, leased=1, done=1),
        StudyState(name="beta", queued=0, leased=1, done=0),
    ]
    assert (queue.worker_count(), queue.study_count(), queue.queued()) == (3, 2, 1)
    assert_counts_add_up(queue)
    assert queue.jobs_done == 1
    assert queue.requeued == 0


def test_requeued_counts_expiries_and_losses() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3"))
    take(queue, "w1")
    take(queue, "w2")
    take(queue, "w3")
    assert queue.requeued == 0

    queue.worker_lost("w2")
    clock.advance(LOST_WORKER_GRACE)
    queue.expire()
    assert queue.requeued == 1
    clock.advance(LEASE_SECONDS)
    queue.expire()  # w1's and w3's leases
    assert queue.requeued == 3
    assert state(queue, "s") == StudyState(name="s", queued=3, leased=0, done=0)


def test_jobs_per_second_over_the_last_minute() -> None:
    queue, clock = make_queue("s")
    assert queue.jobs_per_second() == 0.0
    assert queue.uptime() == 0.0
    queue.submit("s", jobs(*(f"j{n}" for n in range(10))))

    clock.advance(10.0)
    for name in ("w1", "w2", "w3", "w4", "w5"):
        lease = take(queue, name)
        assert hand_in(queue, lease, name) is None
    assert queue.uptime() == 10.0
    assert queue.jobs_per_second() == pytest.approx(5 / 10.0)  # younger than a minute

    clock.advance(THROUGHPUT_WINDOW - 10.0)  # uptime 60 s, the five still in the window
    assert queue.jobs_per_second() == pytest.approx(5 / THROUGHPUT_WINDOW)

    clock.advance(40.0)  # uptime 100 s: the five are 90 s old, out of the window
    assert queue.jobs_per_second() == 0.0
    for name in ("w1", "w2", "w3"):
        lease = take(queue, name)
        assert hand_in(queue, lease, name) is None
    assert queue.jobs_per_second() == pytest.approx(3 / THROUGHPUT_WINDOW)
    assert queue.jobs_done == 8


def test_duplicates_and_strays_do_not_count_toward_throughput() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    lease = take(queue, "w1")
    clock.advance(20.0)
    assert hand_in(queue, lease, "w2") is not None  # forged: not w2's lease
    assert queue.complete("s", "j1", "made-up", "w1", DIGEST) is not None  # forged: no such lease
    assert hand_in(queue, lease, "w1") is None
    assert hand_in(queue, lease, "w1", digest_of("another")) is not None
    assert hand_in(queue, lease, "w1") is None  # the same hand-in retried: taken, not counted
    assert queue.complete("s", "stray", lease.lease_id, "w1", DIGEST) is not None
    assert queue.complete("gone", "j1", lease.lease_id, "w1", DIGEST) is not None
    assert queue.jobs_done == 1
    assert queue.jobs_per_second() == pytest.approx(1 / 20.0)


# --- forged results ----------------------------------------------------------------------------


def test_a_result_under_another_worker_s_lease_is_refused_and_the_job_stays_leased() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    mine = take(queue, "w1")  # j1
    theirs = take(queue, "w2")  # j2

    # w2 hands in j1 under w1's lease id (say it overheard it): the lease is not w2's.
    assert refused(hand_in(queue, mine, "w2"), mine.lease_id)
    # w1 hands in j2, w2's job, under its own lease id: that lease is not one of j2's.
    assert refused(queue.complete("s", "j2", mine.lease_id, "w1", DIGEST), mine.lease_id)

    assert state(queue, "s") == StudyState(name="s", queued=0, leased=2, done=0)
    assert queue.jobs_done == 0 and queue.jobs_per_second() == 0.0
    assert queue.confirm("s", ["j1", "j2"]) == []
    assert worker(queue, "w1") == WorkerState(name="w1", busy=True, job="s/j1", jobs_done=0)
    assert worker(queue, "w2") == WorkerState(name="w2", busy=True, job="s/j2", jobs_done=0)
    # The rightful results still count.
    assert hand_in(queue, mine, "w1") is None
    assert hand_in(queue, theirs, "w2") is None
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=2)
    assert_counts_add_up(queue)


def test_a_result_under_a_made_up_lease_id_is_refused() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    lease = take(queue, "w1")

    for made_up in ("made-up", lease.lease_id + "x", lease.lease_id.upper() + "Q", ""):
        assert refused(queue.complete("s", "j1", made_up, "w1", DIGEST), "j1")
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=1, done=0)
    assert worker(queue, "w1").busy is True

    clock.advance(LEASE_SECONDS)  # the lease still expires as usual: nothing completed it
    queue.expire()
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=0)
    assert queue.requeued == 1
    assert queue.confirm("s", ["j1"]) == []


def test_a_result_for_a_job_never_leased_is_refused_and_it_stays_queued() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    lease = take(queue, "w1")  # j1; j2 was never leased

    assert refused(queue.complete("s", "j2", lease.lease_id, "w1", DIGEST), "j2")
    assert refused(queue.complete("s", "j2", "guess", "w2", DIGEST), "j2")

    assert state(queue, "s") == StudyState(name="s", queued=1, leased=1, done=0)
    assert queue.queued() == 1 and queue.jobs_done == 0
    assert queue.confirm("s", ["j2"]) == []
    assert take(queue, "w2").job.job_id == "j2"  # still there to run
    assert_counts_add_up(queue)


def test_a_late_result_under_an_expired_lease_counts_only_from_its_own_worker() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    first = take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()
    second = take(queue, "w2")  # j1 again, under a new lease

    assert refused(hand_in(queue, first, "w2"), first.lease_id)  # w2 under w1's lease
    assert refused(hand_in(queue, first, "w3"), first.lease_id)  # a stranger under it
    assert refused(hand_in(queue, second, "w1"), second.lease_id)  # w1 under w2's lease
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=1, done=0)
    assert queue.jobs_done == 0

    assert hand_in(queue, first, "w1", digest_of("w1's log")) is None  # late, but its own
    assert queue.confirm("s", ["j1"]) == [
        Accepted(job_id="j1", lease_id=first.lease_id, worker="w1", digest=digest_of("w1's log"))
    ]
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=1)


def test_a_late_result_under_an_expired_lease_of_a_queued_job_completes_it() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    first = take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()  # j1 back in the queue, no one to lease it
    assert queue.queued() == 1

    assert refused(hand_in(queue, first, "w2"), first.lease_id)
    assert queue.queued() == 1
    assert hand_in(queue, first, "w1") is None
    assert queue.queued() == 0
    assert [a.lease_id for a in queue.confirm("s", ["j1"])] == [first.lease_id]
    assert_counts_add_up(queue)


# --- accepted results --------------------------------------------------------------------------


def test_confirm_returns_the_taken_result_s_lease_worker_and_digest_once() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3", "j4"))
    one, two = take(queue, "w1"), take(queue, "w2")  # j1, j2
    take(queue, "w3")  # j3 leased, not done; j4 queued

    assert hand_in(queue, one, "w1", digest_of("j1")) is None
    assert hand_in(queue, two, "w2", digest_of("j2")) is None
    assert refused(hand_in(queue, one, "w1", digest_of("j1 again")), "j1")  # changes nothing

    taken_one = Accepted(job_id="j1", lease_id=one.lease_id, worker="w1", digest=digest_of("j1"))
    taken_two = Accepted(job_id="j2", lease_id=two.lease_id, worker="w2", digest=digest_of("j2"))
    # Nothing for jobs leased, queued, never submitted, or of an unknown study.
    assert queue.confirm("s", ["j3", "j4", "nope"]) == []
    assert queue.confirm("s", []) == []
    assert queue.confirm("other", ["j1"]) == []
    assert queue.confirm("s", ["j2", "j3", "j1"]) == [taken_two, taken_one]  # in the order asked
    # Once confirmed, forgotten: the broker keeps only what its study has not been told.
    assert queue.confirm("s", ["j1", "j2"]) == []
    assert refused(hand_in(queue, one, "w1", digest_of("j1")), "j1")


def test_a_closed_study_s_accepted_results_are_forgotten() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1"))
    assert hand_in(queue, take(queue, "w1"), "w1") is None
    assert len(queue.confirm("s", ["j1"])) == 1

    queue.close_study("s")
    assert queue.confirm("s", ["j1"]) == []
    queue.open_study("s")  # a fresh study under the same name
    assert queue.confirm("s", ["j1"]) == []


def test_a_done_job_run_again_has_its_new_result_accepted() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1"))
    first = take(queue, "w1")
    assert hand_in(queue, first, "w1", digest_of("first")) is None

    queue.submit("s", jobs("j1"))  # its result was lost on the way: run it again
    again = take(queue, "w2")
    assert refused(hand_in(queue, first, "w1", digest_of("stale")), first.lease_id)
    assert hand_in(queue, again, "w2", digest_of("second")) is None
    assert queue.confirm("s", ["j1"]) == [
        Accepted(job_id="j1", lease_id=again.lease_id, worker="w2", digest=digest_of("second"))
    ]


# --- jobs that avoid workers -------------------------------------------------------------------


def test_a_job_avoiding_a_worker_goes_to_another_that_asks() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1", avoid=("w1",)))

    waiter = park(queue, "w1")  # the only job avoids w1: it waits, parked first
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=0)
    lease = take(queue, "w2")
    assert lease.job.job_id == "j1"
    assert lease.job.avoid == ["w1"]

    # w1 is still parked, and takes the next job that does not avoid it.
    submitted = queue.submit("s", jobs("j2"))
    assert [(a.waiter, a.leases[0].job.job_id) for a in submitted.assignments] == [(waiter, "j2")]
    assert_counts_add_up(queue)


def test_a_worker_passes_over_a_job_that_avoids_it_for_the_next() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", [*jobs("j1", avoid=("w1", "w9")), *jobs("j2", "j3")])

    assert take(queue, "w1").job.job_id == "j2"  # j1 stays at the front
    assert take(queue, "w2").job.job_id == "j1"
    assert take(queue, "w3").job.job_id == "j3"
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=3, done=0)
    assert_counts_add_up(queue)


def test_a_parked_worker_a_job_avoids_is_passed_over_for_the_next_parked() -> None:
    queue, _ = make_queue("s")
    first, second, third = park(queue, "w1"), park(queue, "w2"), park(queue, "w3")

    submitted = queue.submit("s", jobs("j1", avoid=("w1", "w2")))
    assert [(a.waiter, a.leases[0].job.job_id) for a in submitted.assignments] == [(third, "j1")]

    # w1 and w2 are still parked, oldest first.
    submitted = queue.submit("s", jobs("j2", "j3"))
    assert [(a.waiter, a.leases[0].job.job_id) for a in submitted.assignments] == [
        (first, "j2"),
        (second, "j3"),
    ]
    assert queue.worker_states() == [
        WorkerState(name="w1", busy=True, job="s/j2", jobs_done=0),
        WorkerState(name="w2", busy=True, job="s/j3", jobs_done=0),
        WorkerState(name="w3", busy=True, job="s/j1", jobs_done=0),
    ]


def test_a_parked_worker_takes_a_later_job_when_the_first_avoids_it() -> None:
    queue, _ = make_queue("s")
    waiter = park(queue, "w1")

    submitted = queue.submit("s", [*jobs("j1", avoid=("w1",)), *jobs("j2")])

    assert [(a.waiter, a.leases[0].job.job_id) for a in submitted.assignments] == [(waiter, "j2")]
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=1, done=0)
    assert take(queue, "w2").job.job_id == "j1"


def test_a_job_avoiding_every_worker_waits() -> None:
    queue, clock = make_queue("s")
    waiters = {name: park(queue, name) for name in ("w1", "w2")}

    submitted = queue.submit("s", jobs("j1", avoid=("w1", "w2")))

    assert submitted.queued == ["j1"] and submitted.assignments == []
    lease, replaced = ask(queue, "w1", Waiter("w1"))  # asking again does not change that
    assert lease is None and replaced is waiters["w1"]
    clock.advance(LEASE_SECONDS)
    assert queue.expire() == []
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=0)
    assert queue.queued() == 1
    assert take(queue, "w3").job.job_id == "j1"  # a worker it does not avoid runs it
    assert queue.withdraw("w2", waiters["w2"]) is True


def test_an_expired_job_is_not_handed_back_to_a_parked_worker_it_avoids() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", avoid=("w2",)))
    take(queue, "w1")
    avoided, other = park(queue, "w2"), park(queue, "w3")

    clock.advance(LEASE_SECONDS)
    assignments = queue.expire()

    assert [(a.waiter, a.leases[0].job.job_id) for a in assignments] == [(other, "j1")]
    assert queue.withdraw("w2", avoided) is True


def test_a_job_a_worker_avoids_lets_another_study_serve_it() -> None:
    queue, _ = make_queue("a", "b")
    queue.submit("b", jobs("b1"))
    assert take(queue, "w0").study == "b"  # b runs one, so a comes first from now on
    queue.submit("a", jobs("a1", avoid=("w1",)))
    queue.submit("b", jobs("b2"))

    assert take(queue, "w1").job.job_id == "b2"  # a's only job avoids w1
    assert take(queue, "w2").job.job_id == "a1"


# --- memory: workers are remembered only while they matter -------------------------------------


def test_made_up_names_asking_for_work_are_forgotten_once_withdrawn() -> None:
    queue, _ = make_queue("s")
    real = park(queue, "w1")  # joined, parked
    queue.worker_joined("w2")  # joined, idle
    flood = {f"ghost-{n:05d}": Waiter(f"ghost-{n:05d}") for n in range(10_000)}

    for name, waiter in flood.items():
        assert ask(queue, name, waiter) == (None, None)  # no work: parked

    assert queue.worker_count() == 10_002
    listed = queue.worker_states()
    assert len(listed) == MAX_LISTED
    assert [w.name for w in listed] == sorted(["w1", "w2", *flood])[:MAX_LISTED]
    assert_counts_add_up(queue)

    for name, waiter in flood.items():
        assert queue.withdraw(name, waiter) is True

    assert queue.worker_count() == 2
    assert queue.worker_states() == [
        WorkerState(name="w1", busy=False, job="", jobs_done=0),
        WorkerState(name="w2", busy=False, job="", jobs_done=0),
    ]
    assert len(queue.worker_states()) <= MAX_LISTED
    submitted = queue.submit("s", jobs("j1"))  # the real parked worker is still served
    assert [a.waiter for a in submitted.assignments] == [real]


def test_a_made_up_name_is_forgotten_once_its_lease_ends() -> None:
    queue, clock = make_queue("s", "t")
    queue.submit("s", jobs("j1", "j2", "j3"))

    # Its result is taken: it holds nothing any more.
    done, _ = ask(queue, "ghost", Waiter("ghost"))
    assert done is not None and done.job.job_id == "j1"
    assert queue.worker_count() == 1
    assert hand_in(queue, done, "ghost") is None
    assert queue.worker_count() == 0 and queue.jobs_done == 1

    # Its lease expires.
    lease, _ = ask(queue, "ghost", Waiter("ghost"))
    assert lease is not None and lease.job.job_id == "j2"
    assert queue.worker_count() == 1
    clock.advance(LEASE_SECONDS)
    queue.expire()
    assert queue.worker_count() == 0 and queue.requeued == 1

    # Its study is closed.
    queue.submit("t", jobs("t1"))
    lease, _ = ask(queue, "ghost", Waiter("ghost"))
    assert lease is not None and lease.study == "t"  # t has been served least recently
    assert queue.close_study("t") == 0
    assert queue.worker_count() == 0

    # It asks again without handing its lease in, is parked (paused), and is withdrawn: it is
    # forgotten; the job it held is queued again, and its late result still counts.
    held, _ = ask(queue, "ghost", Waiter("ghost"))
    assert held is not None and held.job.job_id == "j2"
    waiter = Waiter("ghost")
    assert ask(queue, "ghost", waiter) == (None, None)  # paused: parked
    assert queue.worker_count() == 1
    assert queue.withdraw("ghost", waiter) is True
    assert queue.worker_count() == 0
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=0, done=1)
    assert hand_in(queue, held, "ghost") is None
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=2)
    assert queue.worker_count() == 0
    assert_counts_add_up(queue)


def test_a_joined_worker_is_remembered_while_idle_and_forgotten_when_lost() -> None:
    queue, clock = make_queue("s")
    waiter = park(queue, "w1")
    assert queue.withdraw("w1", waiter) is True
    assert queue.worker_states() == [WorkerState(name="w1", busy=False, job="", jobs_done=0)]

    queue.submit("s", jobs("j1"))
    lease = take(queue, "w1")
    assert hand_in(queue, lease, "w1") is None
    clock.advance(LEASE_SECONDS)
    queue.expire()
    assert queue.worker_states() == [WorkerState(name="w1", busy=False, job="", jobs_done=1)]

    queue.worker_lost("w1")
    assert queue.worker_count() == 0 and queue.worker_states() == []


def test_states_list_the_first_by_name_and_counts_give_the_totals() -> None:
    queue, _ = make_queue()
    names = [f"s{n:03d}" for n in range(MAX_LISTED + 50)]
    for name in reversed(names):
        queue.open_study(name)
        queue.submit(name, jobs("j1", "j2"))
    for n in range(5):
        queue.worker_joined(f"w{n}")

    assert queue.study_count() == MAX_LISTED + 50
    assert [s.name for s in queue.study_states()] == names[:MAX_LISTED]
    assert [s.name for s in queue.study_states(limit=3)] == names[:3]
    assert queue.queued() == 2 * (MAX_LISTED + 50)
    assert queue.worker_count() == 5
    assert [w.name for w in queue.worker_states(limit=2)] == ["w0", "w1"]
    assert queue.worker_states(limit=0) == []
    assert_counts_add_up(queue)


# --- caps and the submission rate --------------------------------------------------------------


def test_jobs_past_a_study_s_cap_are_deferred_until_there_is_room() -> None:
    queue, clock = make_queue("s", "t", max_queued_per_study=3)

    submitted = queue.submit("s", jobs("j1", "j2", "j3", "j4", "j5"))
    assert submitted.queued == ["j1", "j2", "j3"]
    assert submitted.deferred == ["j4", "j5"]
    assert submitted.already_pending == []
    assert queue.queued() == 3 and state(queue, "s").queued == 3
    assert queue.submit("t", jobs("t1", "t2", "t3")).deferred == []  # each study has its cap
    assert_counts_add_up(queue)

    again = queue.submit("s", jobs("j1", "j4"))  # j1 is pending; j4 still has no room
    assert (again.queued, again.already_pending, again.deferred) == ([], ["j1"], ["j4"])

    assert take(queue, "w1").job.job_id == "j1"  # a leased job leaves the queue: room for one
    later = queue.submit("s", jobs("j4", "j5"))
    assert (later.queued, later.deferred) == (["j4"], ["j5"])
    assert state(queue, "s") == StudyState(name="s", queued=3, leased=1, done=0)
    assert_counts_add_up(queue)

    # An expired lease's job comes back though the queue is full: it is not lost.
    clock.advance(LEASE_SECONDS)
    queue.expire()
    assert state(queue, "s") == StudyState(name="s", queued=4, leased=0, done=0)
    assert queue.queued() == 7
    assert queue.submit("s", jobs("j5")).deferred == ["j5"]
    assert_counts_add_up(queue)


def test_jobs_past_the_total_cap_are_deferred_across_studies() -> None:
    queue, _ = make_queue("a", "b", max_queued=4)

    assert queue.submit("a", jobs("a1", "a2", "a3")).queued == ["a1", "a2", "a3"]
    submitted = queue.submit("b", jobs("b1", "b2", "b3"))
    assert (submitted.queued, submitted.deferred) == (["b1"], ["b2", "b3"])
    assert queue.submit("a", jobs("a4")).deferred == ["a4"]
    assert queue.queued() == 4
    assert_counts_add_up(queue)

    lease = take(queue, "w1")
    assert queue.queued() == 3
    assert hand_in(queue, lease, "w1") is None  # done: no change to what is queued
    later = queue.submit("b", jobs("b2", "b3"))
    assert (later.queued, later.deferred) == (["b2"], ["b3"])
    assert queue.queued() == 4

    assert queue.close_study("a") == 2  # a's queue is gone: room for b
    assert queue.queued() == 2
    assert queue.submit("b", jobs("b3")).queued == ["b3"]
    assert_counts_add_up(queue)


def test_a_study_over_its_submission_rate_is_deferred_until_time_passes() -> None:
    rate = 2.0  # jobs per second: bursts of 20
    burst = int(rate * RATE_BURST_SECONDS)
    queue, clock = make_queue("s", "t", submit_rate=rate)
    names = [f"j{n}" for n in range(burst + 5)]

    submitted = queue.submit("s", jobs(*names))
    assert submitted.queued == names[:burst]
    assert submitted.deferred == names[burst:]
    assert queue.queued() == burst
    # Resubmitting pending jobs costs nothing, and each study has its own allowance.
    assert queue.submit("s", jobs("j0")).already_pending == ["j0"]
    assert len(queue.submit("t", jobs(*(f"t{n}" for n in range(burst)))).queued) == burst

    clock.advance(1.0)  # two more
    later = queue.submit("s", jobs(*names[burst:]))
    assert later.queued == names[burst : burst + 2]
    assert later.deferred == names[burst + 2 :]
    assert queue.submit("s", jobs(names[-1])).deferred == [names[-1]]  # none left now

    clock.advance(0.25)  # half a job's worth: not yet
    assert queue.submit("s", jobs(names[-1])).deferred == [names[-1]]
    clock.advance(0.25)
    assert queue.submit("s", jobs(names[-1])).queued == [names[-1]]

    clock.advance(1000.0)  # a long pause earns one burst, not more
    fresh = [f"k{n}" for n in range(burst + 10)]
    submitted = queue.submit("s", jobs(*fresh))
    assert (len(submitted.queued), len(submitted.deferred)) == (burst, 10)
    assert_counts_add_up(queue)


def test_a_deferred_job_is_handed_to_a_parked_worker_once_it_is_queued() -> None:
    queue, clock = make_queue("s", submit_rate=0.1)  # one job at a time, one per 10 s
    waiter = park(queue, "w1")
    first = queue.submit("s", jobs("j1", "j2"))
    assert (first.queued, first.deferred) == (["j1"], ["j2"])
    assert [(a.waiter, a.leases[0].job.job_id) for a in first.assignments] == [(waiter, "j1")]

    later = park(queue, "w2")
    assert queue.submit("s", jobs("j2")).assignments == []  # still deferred
    clock.advance(10.0)
    submitted = queue.submit("s", jobs("j2"))
    assert [(a.waiter, a.leases[0].job.job_id) for a in submitted.assignments] == [(later, "j2")]


# --- totals ------------------------------------------------------------------------------------


def test_queued_counts_every_study_s_queue_through_a_job_s_life() -> None:
    queue, clock = make_queue("a", "b")
    assert queue.queued() == 0
    queue.submit("a", jobs("a1", "a2", "a3"))
    queue.submit("b", jobs("b1", "b2"))
    queue.submit("a", jobs("a1"))  # already pending: not counted twice
    assert queue.queued() == 5
    assert_counts_add_up(queue)

    leases = {name: take(queue, name) for name in ("w1", "w2", "w3")}  # a1, b1, a2
    assert queue.queued() == 2
    assert_counts_add_up(queue)

    assert hand_in(queue, leases["w1"], "w1") is None  # a leased job done: queue unchanged
    assert queue.queued() == 2
    clock.advance(LEASE_SECONDS)
    queue.expire()  # b1 and a2 come back
    assert queue.queued() == 4
    assert_counts_add_up(queue)

    assert hand_in(queue, leases["w3"], "w3") is None  # a2's late result: out of the queue
    assert queue.queued() == 3
    assert refused(hand_in(queue, leases["w3"], "w3", digest_of("another")), "a2")
    assert queue.queued() == 3
    assert_counts_add_up(queue)

    assert take(queue, "w4").job.job_id == "b1"  # b was served less recently than a
    assert queue.queued() == 2
    assert queue.close_study("b") == 1  # b2: its leased b1 was not queued
    assert queue.queued() == 1  # a3
    clock.advance(LEASE_SECONDS)
    assert queue.expire() == []  # the closed study's lease does not come back
    assert queue.queued() == 1
    assert take(queue, "w5").job.job_id == "a3"
    assert queue.queued() == 0
    assert_counts_add_up(queue)


def test_a_slow_submission_rate_still_lets_jobs_through() -> None:
    rate = 0.5 / RATE_BURST_SECONDS  # one job every 20 s: a burst would be worth half a job
    queue, clock = make_queue("s", submit_rate=rate)
    assert queue.submit("s", jobs("j1")).queued == ["j1"]
    assert queue.submit("s", jobs("j2")).deferred == ["j2"]
    clock.advance(1 / rate)
    assert queue.submit("s", jobs("j2")).queued == ["j2"]


# --- batches -----------------------------------------------------------------------------------


def take_batch(queue: Queue, worker: str, want: int) -> list[Lease]:
    """`worker` (a real one) asks for up to `want` jobs and must get at least one at once."""
    queue.worker_joined(worker)
    leases, replaced = queue.request(worker, Waiter(worker), want=want)
    assert leases, f"{worker} got no lease"
    assert replaced is None
    return leases


def test_a_batch_grant_respects_want() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs(*(f"j{n}" for n in range(1, 11))))

    batch = take_batch(queue, "w1", want=3)  # alone: its fair share is the whole queue

    assert [lease.job.job_id for lease in batch] == ["j1", "j2", "j3"]
    assert len({lease.lease_id for lease in batch}) == 3
    assert state(queue, "s") == StudyState(name="s", queued=7, leased=3, done=0)
    assert worker(queue, "w1") == WorkerState(name="w1", busy=True, job="s/j1", jobs_done=0)
    assert queue.busy() == 1  # a worker, however many leases it holds
    for lease in batch:
        assert hand_in(queue, lease, "w1") is None
    assert worker(queue, "w1") == WorkerState(name="w1", busy=False, job="", jobs_done=3)
    assert queue.busy() == 0

    (fourth,) = take_batch(queue, "w1", want=1)
    assert fourth.job.job_id == "j4" and hand_in(queue, fourth, "w1") is None
    rest = take_batch(queue, "w1", want=100)  # more than there is: what there is
    assert [lease.job.job_id for lease in rest] == ["j5", "j6", "j7", "j8", "j9", "j10"]
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=6, done=4)
    assert_counts_add_up(queue)


def test_the_fair_share_spreads_a_shallow_queue_over_free_workers() -> None:
    queue, _ = make_queue("s")
    for name in ("w1", "w2", "w3"):
        queue.worker_joined(name)
    queue.submit("s", jobs(*(f"j{n}" for n in range(1, 7))))

    # Six jobs, three workers: the first to ask does not take them all.
    sizes = [len(take_batch(queue, name, want=10)) for name in ("w1", "w2", "w3")]

    assert sizes == [2, 2, 1]  # ceil(6/3), ceil(4/3), ceil(2/3)
    assert queue.busy() == 3
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=5, done=0)

    # A deep queue: the share does not bind, `want` does.
    queue.submit("s", jobs(*(f"k{n}" for n in range(100))))
    assert len(take_batch(queue, "w4", want=4)) == 4
    assert_counts_add_up(queue)


def test_a_parked_worker_is_woken_with_up_to_the_leases_it_wanted() -> None:
    queue, _ = make_queue("s")
    queue.worker_joined("w1")
    waiter = Waiter("w1")
    assert queue.request("w1", waiter, want=3) == ([], None)  # no work: parked

    submitted = queue.submit("s", jobs("j1", "j2", "j3", "j4", "j5"))

    (assignment,) = submitted.assignments
    assert assignment.waiter is waiter
    assert [lease.job.job_id for lease in assignment.leases] == ["j1", "j2", "j3"]
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=3, done=0)

    # Two parked workers share a shallow queue evenly; one wanting more than there is gets
    # what there is.
    queue, _ = make_queue("s")
    parked = {name: Waiter(name) for name in ("w1", "w2")}
    for name, held in parked.items():
        queue.worker_joined(name)
        assert queue.request(name, held, want=4) == ([], None)
    submitted = queue.submit("s", jobs("j1", "j2", "j3", "j4"))
    assert [
        (a.waiter, [lease.job.job_id for lease in a.leases]) for a in submitted.assignments
    ] == [
        (parked["w1"], ["j1", "j2"]),
        (parked["w2"], ["j3", "j4"]),
    ]
    # Busy workers that hold their token count too: they will soon be free to take a share.
    held = Waiter("w3")
    queue.worker_joined("w3")
    assert queue.request("w3", held, want=5) == ([], None)
    submitted = queue.submit("s", jobs("j5", "j6"))
    assert [
        (a.waiter, [lease.job.job_id for lease in a.leases]) for a in submitted.assignments
    ] == [(held, ["j5"])]
    assert_counts_add_up(queue)


def test_a_parked_worker_wanting_more_than_there_is_gets_what_there_is() -> None:
    queue, _ = make_queue("s")
    waiter = Waiter("w1")
    queue.worker_joined("w1")
    assert queue.request("w1", waiter, want=5) == ([], None)

    submitted = queue.submit("s", jobs("j1", "j2"))

    assert [
        (a.waiter, [lease.job.job_id for lease in a.leases]) for a in submitted.assignments
    ] == [(waiter, ["j1", "j2"])]


def test_wanting_no_lease_never_parks() -> None:
    queue, _ = make_queue("s")
    queue.worker_joined("w1")
    waiter = Waiter("w1")

    assert queue.request("w1", waiter, want=0) == ([], None)

    assert queue.withdraw("w1", waiter) is False  # not parked
    assert queue.submit("s", jobs("j1")).assignments == []
    assert queue.request("w1", waiter, want=0) == ([], None)  # work queued: still none
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=0)

    # It frees the worker of its batch and lets go of a parked request, as any request does.
    lease = take(queue, "w1")
    assert worker(queue, "w1").busy
    assert queue.request("w1", Waiter("w1"), want=0) == ([], None)
    assert not worker(queue, "w1").busy
    parked = park(queue, "w1")
    assert queue.request("w1", Waiter("w1"), want=0) == ([], parked)
    assert queue.submit("s", jobs("j2")).assignments == []
    assert hand_in(queue, lease, "w1") is None  # its lease stood meanwhile

    # A made-up name wanting nothing is not remembered.
    assert queue.request("ghost", Waiter("ghost"), want=0) == ([], None)
    assert queue.worker_count() == 1
    assert_counts_add_up(queue)


def test_every_lease_of_a_lost_worker_goes_back_in_order_after_the_grace() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3", "j4", "j5", "j6"))
    batch = take_batch(queue, "w1", want=3)  # j1, j2, j3
    assert take(queue, "w2").job.job_id == "j4"

    assert queue.worker_lost("w1") == ([], None)
    assert queue.expire() == [] and queue.requeued == 0  # their results may be on the way
    clock.advance(LOST_WORKER_GRACE)
    assert queue.expire() == []

    assert queue.requeued == 3
    assert queue.worker_states() == [WorkerState(name="w2", busy=True, job="s/j4", jobs_done=0)]
    assert state(queue, "s") == StudyState(name="s", queued=5, leased=1, done=0)
    assert job_ids_in_lease_order(queue, 5) == ["j1", "j2", "j3", "j5", "j6"]
    assert all(hand_in(queue, lease, "w1") is None for lease in batch)  # late, still its own
    assert_counts_add_up(queue)


# --- handing in again --------------------------------------------------------------------------


def test_the_same_hand_in_again_is_taken_and_counted_once() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    first = take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()
    second = take(queue, "w2")  # j1 again
    clock.advance(1.0)

    assert hand_in(queue, first, "w1") is None  # w1's late result
    assert hand_in(queue, first, "w1") is None  # its answer was lost: w1 hands it in again

    assert queue.jobs_done == 1
    assert queue.jobs_per_second() == pytest.approx(1 / (LEASE_SECONDS + 1.0))
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=1)
    assert worker(queue, "w1").jobs_done == 1
    # Another digest, or another lease, is another result: refused, as before.
    assert refused(hand_in(queue, first, "w1", digest_of("another")), "done already")
    assert refused(hand_in(queue, second, "w2"), "done already")
    assert refused(queue.complete("s", "j1", first.lease_id, "w2", DIGEST), "done already")
    assert queue.jobs_done == 1
    assert queue.confirm("s", ["j1"]) == [
        Accepted(job_id="j1", lease_id=first.lease_id, worker="w1", digest=DIGEST)
    ]
    assert refused(hand_in(queue, first, "w1"), "no job")  # confirmed: forgotten


# --- collecting accepted results ---------------------------------------------------------------


def accepted_ids(records: list[Accepted]) -> list[str]:
    return [record.job_id for record in records]


def test_collect_pages_through_accepted_results_in_the_order_taken() -> None:
    queue, _ = make_queue("s")
    assert queue.collect("nope", queue.epoch, 0) == ([], 0)
    assert queue.collect("s", None, 0) == ([], 0)
    assert queue.collect("s", queue.epoch, 0) == ([], 0)
    queue.submit("s", jobs("j1", "j2", "j3", "j4", "j5"))
    leases = {lease.job.job_id: lease for lease in take_batch(queue, "w1", want=5)}
    for job_id in ("j3", "j1", "j5", "j2", "j4"):
        assert hand_in(queue, leases[job_id], "w1", digest_of(job_id)) is None

    # A study that knows no serial of this queue's starts from the first; nothing is forgotten.
    records, last = queue.collect("s", None, 0, limit=2)
    assert records == [
        Accepted(job_id="j3", lease_id=leases["j3"].lease_id, worker="w1", digest=digest_of("j3")),
        Accepted(job_id="j1", lease_id=leases["j1"].lease_id, worker="w1", digest=digest_of("j1")),
    ]
    assert last == 2
    everything = ["j3", "j1", "j5", "j2", "j4"]
    assert accepted_ids(queue.collect("s", None, 0)[0]) == everything
    other_epoch = make_queue()[0].epoch
    assert other_epoch != queue.epoch
    assert queue.collect("s", other_epoch, 4) == (queue.collect("s", None, 0)[0], 5)

    # Under this queue's epoch the cursor pages on, and what is behind it is forgotten.
    records, last = queue.collect("s", queue.epoch, 2, limit=2)
    assert (accepted_ids(records), last) == (["j5", "j2"], 4)
    assert accepted_ids(queue.collect("s", None, 0)[0]) == ["j5", "j2", "j4"]
    assert queue.confirm("s", ["j3", "j1"]) == []  # collected: gone
    records, last = queue.collect("s", queue.epoch, last)
    assert (accepted_ids(records), last) == (["j4"], 5)
    assert queue.collect("s", queue.epoch, last) == ([], 5)  # all collected: forgotten
    assert queue.collect("s", None, 0) == ([], 0)
    assert queue.collect("s", queue.epoch, 99) == ([], 5)  # never past the last serial given

    # Serials go on; a job run again has its new result taken as the newest.
    queue.submit("s", jobs("j6", "j3"))
    for lease in take_batch(queue, "w1", want=2):
        assert hand_in(queue, lease, "w1") is None
    records, last = queue.collect("s", queue.epoch, 5)
    assert (accepted_ids(records), last) == (["j6", "j3"], 7)
    assert queue.study_states() == [StudyState(name="s", queued=0, leased=0, done=7)]


def test_confirm_and_collect_share_the_store() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1", "j2", "j3"))
    for lease in take_batch(queue, "w1", want=3):
        assert hand_in(queue, lease, "w1") is None

    assert accepted_ids(queue.confirm("s", ["j2"])) == ["j2"]

    records, last = queue.collect("s", queue.epoch, 0)
    assert (accepted_ids(records), last) == (["j1", "j3"], 3)
    assert queue.collect("s", queue.epoch, last) == ([], 3)
    assert queue.confirm("s", ["j1", "j3"]) == []


def test_without_an_uncollected_cap_the_oldest_results_are_forgotten_past_the_queue_cap() -> None:
    queue, _ = make_queue("s", max_queued_per_study=3)
    for n in range(1, 6):
        queue.submit("s", jobs(f"j{n}"))
        assert hand_in(queue, take(queue, "w1"), "w1") is None  # never held back

    records, last = queue.collect("s", None, 0)
    assert (accepted_ids(records), last) == (["j3", "j4", "j5"], 5)
    assert queue.confirm("s", ["j1", "j2"]) == []
    assert state(queue, "s").done == 5


def test_a_study_at_its_uncollected_cap_gets_no_leases_until_it_collects() -> None:
    queue, _ = make_queue("s", "t", max_uncollected_per_study=2)
    queue.submit("s", jobs("j1", "j2", "j3", "j4", "j5"))
    out = [take(queue, name) for name in ("w1", "w2", "w3")]  # j1, j2, j3
    for lease, name in zip(out, ("w1", "w2", "w3"), strict=True):
        assert hand_in(queue, lease, name) is None  # the leases out still count: none dropped
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=0, done=3)

    waiter = park(queue, "w1")  # s is held back: its jobs wait
    submitted = queue.submit("t", jobs("t1"))  # another study is not
    assert [(a.waiter, a.leases[0].job.job_id) for a in submitted.assignments] == [(waiter, "t1")]
    assert hand_in(queue, submitted.assignments[0].leases[0], "w1") is None
    waiter = park(queue, "w1")
    assert queue.expire() == []
    assert queue.confirm("s", []) == []
    records, last = queue.collect("s", None, 0)  # reading is not collecting: still held back
    assert (accepted_ids(records), last) == (["j1", "j2", "j3"], 3)
    assert queue.expire() == []
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=0, done=3)

    assert queue.collect("s", queue.epoch, 1) == (records[1:], 3)  # two left: at the cap
    assert queue.expire() == []
    assert queue.collect("s", queue.epoch, 3) == ([], 3)
    assignments = queue.expire()  # the ticker's next pass hands the parked worker the job
    assert [(a.waiter, [lease.job.job_id for lease in a.leases]) for a in assignments] == [
        (waiter, ["j4"])
    ]
    assert take(queue, "w3").job.job_id == "j5"
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=2, done=3)
    assert_counts_add_up(queue)


# --- overdue leases: backup copies -------------------------------------------------------------


def held_and_idle(queue: Queue, clock: FakeClock) -> tuple[Lease, Waiter]:
    """w1 runs j1 in 1 s (the study's turnaround); w2 holds j2 and says nothing; w1 waits."""
    queue.submit("s", jobs("j1", "j2"))
    done, held = take(queue, "w1"), take(queue, "w2")
    clock.advance(1.0)
    assert hand_in(queue, done, "w1") is None
    return held, park(queue, "w1")


def test_an_overdue_job_is_copied_to_an_idle_worker_and_the_first_result_counts() -> None:
    queue, clock = make_queue("s")
    held, waiter = held_and_idle(queue, clock)
    clock.advance(SPECULATE_FACTOR * 1.0 - 1.0 - 0.1)  # held just under 3 turnarounds
    assert queue.expire() == []
    clock.advance(0.1)

    (copy,) = queue.expire()

    assert copy.waiter is waiter and copy.leases[0].job.job_id == "j2"
    assert copy.leases[0].lease_id != held.lease_id
    assert (queue.copies, queue.requeued) == (1, 0)
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=1, done=1)
    assert queue.expire() == []  # one copy: the job is not overdue again until the copy is
    assert park(queue, "w3") and queue.expire() == []
    assert hand_in(queue, copy.leases[0], "w1") is None
    assert refused(hand_in(queue, held, "w2"), "done already")
    assert queue.jobs_done == 2 and queue.busy() == 0
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=2)
    park(queue, "w2")  # its job was done by the copy: it gave back nothing
    assert queue.abandoned == 0
    assert_counts_add_up(queue)


def test_an_overdue_holder_that_hands_in_first_wins_and_frees_the_copy_s_worker() -> None:
    queue, clock = make_queue("s")
    held, _ = held_and_idle(queue, clock)
    clock.advance(SPECULATE_FACTOR)
    (copy,) = queue.expire()
    assert hand_in(queue, held, "w2") is None  # the straggler after all
    assert not worker(queue, "w1").busy
    assert refused(hand_in(queue, copy.leases[0], "w1"), "done already")
    assert queue.jobs_done == 2


def test_an_overdue_job_is_not_copied_to_a_past_holder_nor_to_a_worker_it_avoids() -> None:
    queue, clock = make_queue("s", lease_seconds=1e6)
    queue.submit("s", jobs("j1") + jobs("j2", avoid=("w3",)))
    done, _ = take(queue, "w1"), take(queue, "w2")
    clock.advance(1.0)
    assert hand_in(queue, done, "w1") is None
    park(queue, "w2")  # gives j2 back
    assert take(queue, "w4").job.job_id == "j2"
    clock.advance(10 * SPECULATE_FACTOR)  # j2 overdue, w2's pause over
    park(queue, "w3")
    assert queue.expire() == []  # w2 held j2 once, and j2 avoids w3
    copy = take(queue, "w5")  # an idle worker asking gets the copy at once
    assert copy.job.job_id == "j2" and queue.copies == 1


def test_nothing_is_copied_before_the_study_s_first_result() -> None:
    queue, clock = make_queue("s", lease_seconds=1e6)
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    park(queue, "w2")
    clock.advance(1000.0)
    assert queue.expire() == [] and queue.copies == 0


def test_one_late_holder_does_not_lengthen_the_overdue_time() -> None:
    """Overdue is measured by the median turnaround: a holder that hands in late cannot make
    the next holder's job wait longer."""
    queue, clock = make_queue("s", lease_seconds=1e6)
    queue.submit("s", jobs(*(f"j{n}" for n in range(5))))
    quick = [take(queue, f"w{n}") for n in range(3)]
    late = take(queue, "late")
    clock.advance(1.0)
    for n, lease in enumerate(quick):
        assert hand_in(queue, lease, f"w{n}") is None
    clock.advance(100.0)
    assert hand_in(queue, late, "late") is None  # a 101 s turnaround among three of 1 s
    held = take(queue, "holder")
    park(queue, "w0")
    clock.advance(SPECULATE_FACTOR * 1.0)
    (copy,) = queue.expire()
    assert copy.leases[0].job.job_id == held.job.job_id
