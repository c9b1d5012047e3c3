"""The broker's scheduling core, LeaseQueue: pure Python on a fake clock, no Zenoh, no threads."""

from collections import Counter
from dataclasses import dataclass

import pytest

from broker.queue import (
    LOST_WORKER_GRACE,
    THROUGHPUT_WINDOW,
    Assignment,
    LeaseQueue,
    UnknownStudy,
)
from schemas.episode import EpisodeSpec
from schemas.gains import PDGains
from schemas.wire import Job, Lease, StudyState, WorkerState
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


def make_queue(*studies: str, lease_seconds: float = LEASE_SECONDS) -> tuple[Queue, FakeClock]:
    clock = FakeClock()
    queue: Queue = LeaseQueue(lease_seconds=lease_seconds, clock=clock)
    for study in studies:
        queue.open_study(study)
    return queue, clock


def jobs(*job_ids: str) -> list[Job]:
    return [Job(job_id=job_id, spec=EPISODE) for job_id in job_ids]


def take(queue: Queue, worker: str) -> Lease:
    """`worker` asks for work and must get a lease straight away."""
    lease, replaced = queue.request(worker, Waiter(worker))
    assert lease is not None, f"{worker} got no lease"
    assert replaced is None
    return lease


def park(queue: Queue, worker: str) -> Waiter:
    """`worker` asks for work and must be parked."""
    waiter = Waiter(worker)
    lease, replaced = queue.request(worker, waiter)
    assert lease is None, f"{worker} got {lease}"
    assert replaced is None
    return waiter


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
    lease, replaced = queue.request("w1", Waiter("w1"))
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
    assert assignment.lease.study == "s"
    assert assignment.lease.job.job_id == "j1"
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
    assert [(a.waiter, a.lease.job.job_id) for a in one.assignments] == [(first, "j1")]

    two = queue.submit("s", jobs("j2", "j3", "j4"))
    assert [(a.waiter, a.lease.job.job_id) for a in two.assignments] == [
        (second, "j2"),
        (third, "j3"),
    ]
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=3, done=0)


def test_a_second_request_from_the_same_worker_replaces_its_parked_waiter() -> None:
    queue, _ = make_queue("s")
    old = park(queue, "w1")
    new = Waiter("w1")

    lease, replaced = queue.request("w1", new)

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
    assert assignments[0].lease.job.job_id == "j1"
    assert assignments[0].lease.lease_id != old.lease_id
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

    assert [(a.waiter, a.lease.job.job_id) for a in assignments] == [(waiter, "j1")]
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


def test_a_worker_asking_again_before_its_result_arrives_keeps_its_lease() -> None:
    """The result travels on another key than the next request and may arrive after it: the
    lease must stand (not be requeued and run twice) until the result or the expiry."""
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    first = take(queue, "w1")
    assert first.job.job_id == "j1"

    second = take(queue, "w1")  # asks again; its result for j1 is still in flight

    assert queue.requeued == 0
    assert second.job.job_id == "j2"
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=2, done=0)
    assert worker(queue, "w1") == WorkerState(name="w1", busy=True, job="s/j2", jobs_done=0)
    assert queue.complete("s", "j1", "w1") is True  # the result, late
    assert worker(queue, "w1") == WorkerState(name="w1", busy=True, job="s/j2", jobs_done=1)
    clock.advance(LEASE_SECONDS)
    queue.expire()  # had the result been lost, the expiry would have taken j1 back
    assert queue.requeued == 1 and state(queue, "s").queued == 1


# --- results -----------------------------------------------------------------------------------


def test_only_the_first_result_for_a_job_counts() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    take(queue, "w1")
    clock.advance(1.0)

    assert queue.complete("s", "j1", "w1") is True
    assert queue.complete("s", "j1", "w1") is False  # duplicate
    assert queue.complete("s", "nope", "w1") is False  # stray: never submitted
    assert queue.complete("other", "j1", "w1") is False  # unknown study

    assert queue.jobs_done == 1
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=1)
    assert worker(queue, "w1") == WorkerState(name="w1", busy=False, job="", jobs_done=1)


def test_a_result_for_a_closed_study_is_not_counted() -> None:
    queue, _ = make_queue("s")
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    queue.close_study("s")

    assert queue.complete("s", "j1", "w1") is False
    assert queue.jobs_done == 0
    assert worker(queue, "w1").jobs_done == 0

    queue.open_study("s")  # reopened under the same name: a fresh study
    assert queue.complete("s", "j1", "w1") is False
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=0)


def test_a_late_result_for_an_expired_and_requeued_job_completes_it() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1", "j2"))
    take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()
    assert state(queue, "s") == StudyState(name="s", queued=2, leased=0, done=0)

    assert queue.complete("s", "j1", "w1") is True  # w1 was slow, not dead

    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=1)
    assert queue.jobs_done == 1
    assert take(queue, "w2").job.job_id == "j2"
    park(queue, "w3")  # j1 is not leased again
    assert queue.complete("s", "j1", "w1") is False


def test_a_late_result_for_an_expired_and_re_leased_job_completes_it_once() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()
    take(queue, "w2")  # j1 again

    assert queue.complete("s", "j1", "w1") is True  # w1's late result
    # w1 gets the credit; w2 is still busy with the job until it asks for work again.
    assert worker(queue, "w1") == WorkerState(name="w1", busy=False, job="", jobs_done=1)
    assert worker(queue, "w2").busy and worker(queue, "w2").jobs_done == 0
    assert queue.complete("s", "j1", "w2") is False  # w2's result, a duplicate
    assert queue.jobs_done == 1
    assert state(queue, "s") == StudyState(name="s", queued=0, leased=0, done=1)
    park(queue, "w2")  # asking again frees it, and the done job is not requeued
    assert not worker(queue, "w2").busy and state(queue, "s").queued == 0
    assert queue.requeued == 1


def test_a_result_overtaken_by_its_worker_s_departure_still_completes_the_job() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    waiter = park(queue, "w2")
    queue.worker_lost("w1")  # a worker stopped with SIGTERM: its token's loss came first
    clock.advance(LOST_WORKER_GRACE / 2)

    assert queue.complete("s", "j1", "w1") is True
    clock.advance(LOST_WORKER_GRACE)
    assert queue.expire() == []  # nothing to run twice
    assert queue.requeued == 0 and queue.withdraw("w2", waiter) is True


def test_a_result_after_the_worker_was_lost_completes_the_requeued_job() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    queue.worker_lost("w1")
    clock.advance(LOST_WORKER_GRACE)
    queue.expire()
    assert state(queue, "s").queued == 1

    assert queue.complete("s", "j1", "w1") is True
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
    take(queue, "w1")
    assert queue.complete("s", "j1", "w1") is True

    submitted = queue.submit("s", jobs("j1"))

    assert submitted.queued == ["j1"]
    assert submitted.already_pending == []
    assert state(queue, "s") == StudyState(name="s", queued=1, leased=0, done=1)
    assert take(queue, "w1").job.job_id == "j1"
    assert queue.complete("s", "j1", "w1") is True  # its new result counts
    assert queue.jobs_done == 2


def test_the_same_job_id_in_two_studies_is_two_jobs() -> None:
    queue, _ = make_queue("a", "b")
    assert queue.submit("a", jobs("j1")).queued == ["j1"]
    assert queue.submit("b", jobs("j1")).queued == ["j1"]
    take(queue, "w1")
    take(queue, "w2")
    assert queue.complete("a", "j1", "w1") is True
    assert queue.complete("b", "j1", "w1") is True
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
    for name in workers:
        handed.append(take(queue, name).study)
    for _ in range(8):
        for name in workers:
            held = worker(queue, name).job
            study, job_id = held.split("/")
            assert queue.complete(study, job_id, name) is True
            handed.append(take(queue, name).study)
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
    assert queue.complete("b", leases["w2"].job.job_id, "w2") is True
    assert queue.complete("b", leases["w4"].job.job_id, "w4") is True
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
    assert [a.lease.study for a in assignments] == ["a", "b", "a"]
    assert state(queue, "a") == StudyState(name="a", queued=1, leased=2, done=0)
    assert state(queue, "b") == StudyState(name="b", queued=0, leased=1, done=0)


# --- reporting ---------------------------------------------------------------------------------


def test_worker_and_study_states_report_the_farm() -> None:
    queue, _ = make_queue("beta", "alpha")
    queue.worker_joined("zed")
    queue.worker_joined("zed")  # twice: still one worker
    assert queue.worker_states() == [WorkerState(name="zed", busy=False, job="", jobs_done=0)]
    queue.submit("alpha", jobs("a1", "a2", "a3"))
    assert take(queue, "w1").job.job_id == "a1"
    queue.submit("beta", jobs("b1"))
    assert take(queue, "w2").job.job_id == "b1"  # beta runs fewer
    assert queue.complete("alpha", "a1", "w1") is True
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
        assert queue.complete("s", lease.job.job_id, name) is True
    assert queue.uptime() == 10.0
    assert queue.jobs_per_second() == pytest.approx(5 / 10.0)  # younger than a minute

    clock.advance(THROUGHPUT_WINDOW - 10.0)  # uptime 60 s, the five still in the window
    assert queue.jobs_per_second() == pytest.approx(5 / THROUGHPUT_WINDOW)

    clock.advance(40.0)  # uptime 100 s: the five are 90 s old, out of the window
    assert queue.jobs_per_second() == 0.0
    for name in ("w1", "w2", "w3"):
        lease = take(queue, name)
        assert queue.complete("s", lease.job.job_id, name) is True
    assert queue.jobs_per_second() == pytest.approx(3 / THROUGHPUT_WINDOW)
    assert queue.jobs_done == 8


def test_duplicates_and_strays_do_not_count_toward_throughput() -> None:
    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    take(queue, "w1")
    clock.advance(20.0)
    queue.complete("s", "j1", "w1")
    queue.complete("s", "j1", "w1")
    queue.complete("s", "stray", "w1")
    queue.complete("gone", "j1", "w1")
    assert queue.jobs_done == 1
    assert queue.jobs_per_second() == pytest.approx(1 / 20.0)
