"""The broker on a real Zenoh router: scheduling over the wire, liveliness, hand-ins and
confirmations, bad messages."""

import contextlib
import hashlib
import json
import logging
import time
from collections.abc import Iterator

import pytest
import zenoh

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.queue import MAX_LISTED
from gainfarm.broker.service import Broker
from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.wire import (
    MAX_CONFIRM_JOBS,
    MAX_MESSAGE_BYTES,
    MAX_SUBMISSION_JOBS,
    PROTOCOL_VERSION,
    Accepted,
    BrokerStatus,
    ConfirmReply,
    ConfirmRequest,
    LeaseReply,
    LeaseRequest,
    Submission,
    SubmitReply,
    decode,
)
from tests.helpers import (
    ask_for_work,
    hand_in,
    maximal_job,
    open_studies,
    open_study,
    query,
    result_for,
    short_spec,
    submit,
    wait_for,
)


def status(session: zenoh.Session) -> BrokerStatus:
    ok, payload = query(session, keys.STATUS)
    assert ok
    return decode(BrokerStatus, payload)


def confirm(session: zenoh.Session, study: str, job_ids: list[str]) -> list[Accepted]:
    request = ConfirmRequest(study=study, job_ids=job_ids)
    ok, payload = query(session, keys.confirm(study), request.to_bytes())
    assert ok, payload
    reply = decode(ConfirmReply, payload)
    assert reply.study == study
    return reply.accepted


def join(session: zenoh.Session, broker: Broker, worker: str) -> zenoh.LivelinessToken:
    """Hold `worker`'s liveliness token, as a worker does, until the broker knows it.

    Keep the token: Zenoh undeclares it when it is garbage-collected."""
    token = session.liveliness().declare_token(keys.alive_worker(worker))
    wait_for(
        lambda: any(state.name == worker for state in broker.queue.worker_states()),
        what=f"the broker to see worker {worker}",
    )
    return token


@contextlib.contextmanager
def own_broker(**options: object) -> Iterator[tuple[Broker, zenoh.Session]]:
    """A broker with options of its own, and a client session connected to it."""
    with Broker([f"tcp/127.0.0.1:{free_port()}"], **options) as broker:
        session = open_session("client", connect=broker.endpoints)
        try:
            yield broker, session
        finally:
            session.close()


# --- scheduling -------------------------------------------------------------------------------


def test_a_job_is_leased_to_a_free_worker_and_completed_by_its_result(
    broker: Broker, session: zenoh.Session
) -> None:
    _s = open_study(session, broker, "s")
    _w = join(session, broker, "w")
    reply = submit(session, "s", {"j1": short_spec()})
    assert reply.queued == ["j1"] and not reply.rejected and not reply.deferred
    lease = ask_for_work(session, "w")
    assert lease is not None and lease.job.job_id == "j1" and lease.study == "s"
    assert lease.job.spec == short_spec()
    assert confirm(session, "s", ["j1"]) == []  # nothing handed in yet
    log = b"an episode log"
    result = result_for(
        "s", "j1", worker="w", lease_id=lease.lease_id, digest=hashlib.sha256(log).hexdigest()
    )
    verdict = hand_in(session, result)
    assert verdict.accepted and verdict.reason == ""
    assert broker.queue.jobs_done == 1
    farm = status(session)
    assert farm.studies[0].done == 1 and farm.studies[0].leased == 0
    assert [(worker.name, worker.busy, worker.jobs_done) for worker in farm.workers] == [
        ("w", False, 1)
    ]
    assert confirm(session, "s", ["j1"]) == [
        Accepted(
            job_id="j1",
            lease_id=lease.lease_id,
            worker="w",
            digest=result.digest,
            scores=result.scores,
        )
    ]
    # The same result handed in again is a duplicate: refused, and the job counted once.
    again = hand_in(session, result)
    assert not again.accepted and "no job 'j1' waits for a result" in again.reason
    assert ask_for_work(session, "w") is None  # also proves the broker still serves
    assert broker.queue.jobs_done == 1


def test_a_free_worker_waits_for_work_and_gets_it_as_soon_as_it_is_submitted(
    broker: Broker, session: zenoh.Session
) -> None:
    _s = open_study(session, broker, "s")
    waiting = session.get(keys.lease("w"), payload=LeaseRequest(worker="w").to_bytes(), timeout=5.0)
    wait_for(lambda: status(session).workers, what="the worker's request to be held")
    submit(session, "s", {"j1": short_spec()})
    replies = list(waiting)
    assert len(replies) == 1
    (lease,) = decode(LeaseReply, replies[0].ok.payload.to_bytes()).leases
    assert lease.job.job_id == "j1"


@pytest.mark.slow
def test_a_dead_workers_job_goes_straight_to_another_worker(
    broker: Broker, session: zenoh.Session
) -> None:
    _s = open_study(session, broker, "s")
    submit(session, "s", {"j1": short_spec()})
    doomed = open_session("client", connect=broker.endpoints)
    _doomed = doomed.liveliness().declare_token(keys.alive_worker("doomed"))
    assert ask_for_work(doomed, "doomed").job.job_id == "j1"
    assert ask_for_work(session, "other") is None  # held for the hold time, then "no work"
    doomed.close()  # its liveliness token vanishes with its session
    wait_for(lambda: broker.queue.requeued == 1, what="the dead worker's job to be requeued")
    lease = ask_for_work(session, "other")
    assert lease is not None and lease.job.job_id == "j1"


def test_an_expired_lease_goes_back_to_the_queue() -> None:
    with own_broker(lease_seconds=0.2) as (broker, session):
        _token = open_study(session, broker, "s")
        submit(session, "s", {"j1": short_spec()})
        first = ask_for_work(session, "hung")
        second = ask_for_work(session, "other")  # held until the first lease expires
        assert first is not None and second is not None
        assert first.job.job_id == second.job.job_id == "j1"
        assert first.lease_id != second.lease_id
        assert broker.queue.requeued == 1


def test_a_study_whose_analytic_process_goes_has_its_queued_jobs_dropped(
    broker: Broker, session: zenoh.Session
) -> None:
    analytic = open_session("client", connect=broker.endpoints)
    _token = open_study(analytic, broker, "gone")
    submit(analytic, "gone", {f"j{n}": short_spec() for n in range(3)})
    assert status(session).studies[0].queued == 3
    analytic.close()
    wait_for(lambda: "gone" not in open_studies(broker.queue), what="the study to be closed")
    assert status(session).studies == []
    assert ask_for_work(session, "w") is None


def test_jobs_for_an_unknown_study_are_rejected_with_a_reason(session: zenoh.Session) -> None:
    reply = submit(session, "nobody", {"j1": short_spec()})
    assert reply.queued == []
    assert [rejection.job_id for rejection in reply.rejected] == ["j1"]
    assert "unknown study 'nobody'" in reply.rejected[0].reason


def test_two_studies_share_the_workers(broker: Broker, session: zenoh.Session) -> None:
    _a = open_study(session, broker, "a")
    _b = open_study(session, broker, "b")
    submit(session, "a", {f"a{n}": short_spec() for n in range(10)})
    submit(session, "b", {f"b{n}": short_spec() for n in range(10)})
    leased = [ask_for_work(session, f"w{n}").study for n in range(6)]
    assert leased.count("a") == leased.count("b") == 3


# --- queue caps -------------------------------------------------------------------------------


def test_jobs_past_a_studys_queue_cap_are_deferred_not_rejected() -> None:
    with own_broker(max_queued_per_study=3) as (broker, session):
        _s = open_study(session, broker, "s")
        reply = submit(session, "s", {f"j{n}": short_spec() for n in range(5)})
        assert reply.queued == ["j0", "j1", "j2"]
        assert reply.deferred == ["j3", "j4"] and not reply.rejected
        assert status(session).queued == 3
        # A worker takes one: there is room again for one of those deferred.
        assert ask_for_work(session, "w").job.job_id == "j0"
        again = submit(session, "s", {"j3": short_spec(), "j4": short_spec()})
        assert again.queued == ["j3"] and again.deferred == ["j4"]


def test_jobs_past_the_brokers_queue_cap_are_deferred_whichever_study_sends_them() -> None:
    with own_broker(max_queued=4, max_queued_per_study=3) as (broker, session):
        _a = open_study(session, broker, "a")
        _b = open_study(session, broker, "b")
        assert submit(session, "a", {f"a{n}": short_spec() for n in range(3)}).queued == [
            "a0",
            "a1",
            "a2",
        ]
        reply = submit(session, "b", {f"b{n}": short_spec() for n in range(3)})
        assert reply.queued == ["b0"] and reply.deferred == ["b1", "b2"]
        farm = status(session)
        assert farm.queued == 4 and [study.queued for study in farm.studies] == [3, 1]


def test_jobs_past_a_studys_submission_rate_are_deferred() -> None:
    with own_broker(submit_rate=0.2) as (broker, session):  # a burst of 2 jobs, then 1 per 5 s
        _s = open_study(session, broker, "s")
        reply = submit(session, "s", {f"j{n}": short_spec() for n in range(4)})
        assert reply.queued == ["j0", "j1"] and reply.deferred == ["j2", "j3"]


def test_the_largest_submission_and_confirmation_are_answered_over_the_wire() -> None:
    """MAX_SUBMISSION_JOBS of the largest Job there is: every one queued, the reply decodes;
    then a question about MAX_CONFIRM_JOBS of the longest names."""
    with own_broker(max_queued_per_study=MAX_SUBMISSION_JOBS) as (broker, session):
        _s = open_study(session, broker, "s")
        jobs = [maximal_job(n) for n in range(MAX_SUBMISSION_JOBS)]
        raw = Submission(study="s", jobs=jobs).to_bytes()
        assert 3_000_000 < len(raw) <= MAX_MESSAGE_BYTES
        ok, payload = query(session, keys.submit("s"), raw)
        assert ok, payload
        reply = decode(SubmitReply, payload)
        assert reply.queued + reply.deferred == [job.job_id for job in jobs]
        assert not reply.rejected and len(reply.queued) > 0
        names = [f"{n:064d}" for n in range(MAX_CONFIRM_JOBS)]
        assert confirm(session, "s", names) == []  # nothing handed in: asked and answered
        assert status(session).rejected == 0


# --- hand-ins and confirmations ---------------------------------------------------------------


def test_only_the_lease_holder_can_hand_in_a_result(broker: Broker, session: zenoh.Session) -> None:
    """A result under another worker's lease, under a made-up lease id, under the worker's own
    lease of another job, or on another worker's key is refused with a reason; the job's
    worker can still hand in its own result."""
    _s = open_study(session, broker, "s")
    _tokens = [join(session, broker, worker) for worker in ("w1", "w2")]
    submit(session, "s", {"j1": short_spec(), "j2": short_spec()})
    mine, theirs = ask_for_work(session, "w1"), ask_for_work(session, "w2")
    assert (mine.job.job_id, theirs.job.job_id) == ("j1", "j2")
    assert mine.lease_id != theirs.lease_id
    farm = status(session)
    assert [(w.name, w.job) for w in farm.workers] == [("w1", "s/j1"), ("w2", "s/j2")]

    refusals = [
        (result_for("s", "j1", worker="w2", lease_id=mine.lease_id), "handed to another worker"),
        (result_for("s", "j1", worker="w1", lease_id="made-up"), "is not one of job 'j1'"),
        (result_for("s", "j1", worker="w2", lease_id=theirs.lease_id), "is not one of job 'j1'"),
        (result_for("s", "nope", worker="w1", lease_id=mine.lease_id), "no job 'nope'"),
        (result_for("other", "j1", worker="w1", lease_id=mine.lease_id), "unknown study"),
    ]
    for forged, reason in refusals:
        verdict = hand_in(session, forged)
        assert not verdict.accepted and reason in verdict.reason, (forged, verdict)
    # The holder's own result, on another worker's key: the key and the message disagree.
    own = result_for("s", "j1", worker="w1", lease_id=mine.lease_id)
    request = LeaseRequest(worker="w1", want=0, results=[own])
    ok, reason = query(session, keys.lease("w2"), request.to_bytes())
    assert not ok and reason.decode() == "the message's worker 'w1' is not the key's 'w2'"

    assert broker.queue.jobs_done == 0 and broker.rejected == len(refusals) + 1
    farm = status(session)
    # Each request handed in nothing of its worker's own: their leases were given back, and the
    # jobs are queued again (a worker asks only once done with its batch).
    assert [(study.queued, study.leased, study.done) for study in farm.studies] == [(2, 0, 0)]
    assert confirm(session, "s", ["j1", "j2"]) == []
    verdict = hand_in(session, own)
    assert verdict.accepted, verdict.reason
    assert [accepted.worker for accepted in confirm(session, "s", ["j1", "j2"])] == ["w1"]


def lease_batch(
    session: zenoh.Session, worker: str, want: int, results: list | None = None
) -> tuple[LeaseReply, float]:
    """A worker's request for `want` leases that hands `results` in: the reply, and how long
    the broker took to answer it."""
    request = LeaseRequest(worker=worker, want=want, results=results or [])
    asked = time.monotonic()
    ok, payload = query(session, keys.lease(worker), request.to_bytes())
    assert ok, payload
    return decode(LeaseReply, payload), time.monotonic() - asked


@pytest.mark.slow
def test_a_worker_takes_a_batch_and_hands_it_in_with_its_next_request() -> None:
    """A batch is at most what was asked; its results ride on the next request, each with a
    verdict in order; a request that hands results in is answered at once even with no work
    left (its worker waits for the verdicts), one that hands nothing in is held."""
    with own_broker(hold_seconds=4.0) as (broker, session):
        _batch_and_hand_in(broker, session)


def _batch_and_hand_in(broker: Broker, session: zenoh.Session) -> None:
    _s = open_study(session, broker, "s")
    _w = join(session, broker, "w")
    submit(session, "s", {f"j{n}": short_spec() for n in range(5)})
    first, _ = lease_batch(session, "w", want=3)
    assert [lease.job.job_id for lease in first.leases] == ["j0", "j1", "j2"]
    assert first.verdicts == [] and broker.queue.busy() == 1
    done = [
        result_for("s", lease.job.job_id, "w", lease_id=lease.lease_id) for lease in first.leases
    ]
    forged = result_for("s", "j3", "w", lease_id="made-up")  # j3 is queued, not this worker's
    second, _ = lease_batch(session, "w", want=3, results=[*done, forged])
    assert [(v.job_id, v.accepted) for v in second.verdicts] == [
        ("j0", True),
        ("j1", True),
        ("j2", True),
        ("j3", False),
    ]
    assert "is not one of job 'j3'" in second.verdicts[3].reason
    assert [lease.job.job_id for lease in second.leases] == ["j3", "j4"]  # all that is left
    last = [
        result_for("s", lease.job.job_id, "w", lease_id=lease.lease_id) for lease in second.leases
    ]
    third, took = lease_batch(session, "w", want=3, results=last)
    assert [v.accepted for v in third.verdicts] == [True, True] and third.leases == []
    assert took < broker.hold_seconds / 2  # answered at once, not held for work
    held, took = lease_batch(session, "w", want=3)
    assert held == LeaseReply() and took >= broker.hold_seconds * 0.9
    assert broker.queue.jobs_done == 5 and broker.rejected == 1
    assert [a.job_id for a in confirm(session, "s", [f"j{n}" for n in range(5)])] == [
        f"j{n}" for n in range(5)
    ]


def test_a_batch_is_at_most_a_fair_share_of_the_queue(
    broker: Broker, session: zenoh.Session
) -> None:
    """A shallow queue is spread over the free workers, not taken by the first to ask."""
    _s = open_study(session, broker, "s")
    _tokens = [join(session, broker, worker) for worker in ("w1", "w2", "w3")]
    submit(session, "s", {f"j{n}": short_spec() for n in range(6)})
    greedy, _ = lease_batch(session, "w1", want=32)
    assert len(greedy.leases) == 2  # 6 queued, 3 free workers
    second, _ = lease_batch(session, "w2", want=32)
    assert len(second.leases) == 2  # 4 queued, 3 workers


def test_a_study_is_told_only_its_own_accepted_results(
    broker: Broker, session: zenoh.Session
) -> None:
    _tokens = [open_study(session, broker, study) for study in ("s", "other")]
    submit(session, "s", {"j": short_spec()})
    submit(session, "other", {"j": short_spec()})  # the same job id, in another study
    lease = ask_for_work(session, "w")
    assert lease.study == "s"  # a tie between the studies goes to the one opened first
    assert hand_in(session, result_for("s", "j", worker="w", lease_id=lease.lease_id)).accepted
    assert [accepted.lease_id for accepted in confirm(session, "s", ["j", "nope"])] == [
        lease.lease_id
    ]
    assert confirm(session, "other", ["j"]) == []
    # Another study's confirmation asked on one's own key: the key and the message disagree.
    request = ConfirmRequest(study="s", job_ids=["j"])
    ok, reason = query(session, keys.confirm("other"), request.to_bytes())
    assert not ok and reason.decode() == "the message's study 's' is not the key's 'other'"
    assert broker.rejected == 1


KEYED = [
    (keys.submit("other"), Submission(study="s", jobs=[]), "study 's' is not the key's 'other'"),
    (keys.lease("other"), LeaseRequest(worker="w"), "worker 'w' is not the key's 'other'"),
    (
        keys.lease("other"),
        LeaseRequest(worker="w", want=0, results=[result_for("s", "j", worker="w")]),
        "worker 'w' is not the key's",
    ),
    (
        keys.confirm("other"),
        ConfirmRequest(study="s", job_ids=["j"]),
        "study 's' is not the key's 'other'",
    ),
    (keys.LEASE_ANY, LeaseRequest(worker="w"), "worker 'w' is not the key's '*'"),
]


@pytest.mark.parametrize(
    ("key", "message", "reason"), KEYED, ids=["submit", "lease", "complete", "confirm", "wild"]
)
def test_a_message_must_name_whom_its_key_names(
    broker: Broker, session: zenoh.Session, key: str, message, reason: str
) -> None:
    _s = open_study(session, broker, "s")
    submit(session, "s", {"j": short_spec()})
    ok, said = query(session, key, message.to_bytes())
    assert not ok and reason in said.decode()
    farm = status(session)
    assert farm.rejected == 1 and farm.queued == 1 and farm.workers == []


# --- bad messages -----------------------------------------------------------------------------

QUERYABLES = {
    "submit": keys.submit("s"),
    "lease": keys.lease("w"),
    "confirm": keys.confirm("s"),
}
BAD_PAYLOADS = {
    "json": b"{oops",
    "version": b'{"protocol": 99, "worker": "w", "study": "s", "jobs": []}',
    "schema": b'{"protocol": %d, "unexpected": true}' % PROTOCOL_VERSION,
    # Over a wire message, within what the router takes (a larger one it drops on the way:
    # tests/broker/test_key_flood.py): refused by its size.
    "oversized": b"x" * (MAX_MESSAGE_BYTES + 1),
    "empty": None,
}


@pytest.mark.parametrize("key", QUERYABLES.values(), ids=QUERYABLES.keys())
@pytest.mark.parametrize("payload", BAD_PAYLOADS.values(), ids=BAD_PAYLOADS.keys())
def test_a_bad_query_is_refused_with_a_reason_and_the_broker_serves_on(
    broker: Broker, session: zenoh.Session, key: str, payload: bytes | None, caplog
) -> None:
    with caplog.at_level(logging.WARNING, logger="gainfarm.broker"):
        ok, reason = query(session, key, payload)
    assert not ok
    assert reason.decode() in caplog.text and "\n" not in reason.decode()
    words = ("JSON", "protocol", "missing", "unknown", "limit", "empty")
    assert any(word in reason.decode() for word in words), reason
    assert status(session).rejected == 1
    _s = open_study(session, broker, "s")
    assert submit(session, "s", {"j": short_spec()}).queued == ["j"]
    lease = ask_for_work(session, "w")
    assert lease.job.job_id == "j"
    assert hand_in(session, result_for("s", "j", worker="w", lease_id=lease.lease_id)).accepted
    assert [accepted.job_id for accepted in confirm(session, "s", ["j"])] == ["j"]


NESTED = {"lists": b"[" * 100_000, "objects": b'{"a":' * 100_000}


@pytest.mark.parametrize("key", QUERYABLES.values(), ids=QUERYABLES.keys())
@pytest.mark.parametrize("payload", NESTED.values(), ids=NESTED.keys())
def test_json_nested_past_any_depth_is_a_one_line_refusal(
    broker: Broker, session: zenoh.Session, key: str, payload: bytes
) -> None:
    ok, reason = query(session, key, payload)
    assert not ok
    assert reason and b"\n" not in reason and len(reason) < 400
    assert b"not JSON" in reason, reason
    assert status(session).rejected == 1  # and it serves on


def _handed_in(result: dict) -> bytes:
    return json.dumps(
        {"protocol": PROTOCOL_VERSION, "worker": "w", "want": 0, "results": [result]}
    ).encode()


@pytest.mark.parametrize(
    "payload",
    [
        None,
        b"nonsense",
        _handed_in({"protocol": PROTOCOL_VERSION, "study": "s"}),
        _handed_in({**json.loads(result_for("s", "j", worker="other").to_bytes())}),
    ],
    ids=["none", "json", "schema", "another-worker-s"],
)
def test_a_bad_hand_in_is_refused_with_a_reason_and_the_lease_stands(
    broker: Broker, session: zenoh.Session, payload: bytes | None, caplog
) -> None:
    _s = open_study(session, broker, "s")
    submit(session, "s", {"j": short_spec()})
    lease = ask_for_work(session, "w")
    with caplog.at_level(logging.WARNING, logger="gainfarm.broker"):
        ok, reason = query(session, keys.lease("w"), payload)
    assert not ok and reason.decode() in caplog.text
    assert reason.decode().startswith("LeaseRequest: ")
    # A result sent straight to the study's key is not the broker's business: it does not listen.
    session.put(keys.result("s", "j"), b"", attachment=result_for("s", "j").to_bytes())
    assert broker.queue.jobs_done == 0 and broker.rejected == 1
    assert status(session).studies[0].leased == 1  # the lease stands: a real result may come
    assert hand_in(session, result_for("s", "j", worker="w", lease_id=lease.lease_id)).accepted
    assert broker.queue.jobs_done == 1


# --- many made-up workers ---------------------------------------------------------------------

MADE_UP = 10_000


@pytest.mark.slow
def test_ten_thousand_made_up_workers_leave_the_status_small_and_are_forgotten() -> None:
    """Lease requests from 10,000 names that never joined are held and answered "no work"; the
    status lists a bounded number of them meanwhile, and none once they are answered."""
    with own_broker(hold_seconds=3.0) as (broker, session):
        real = open_session("client", connect=broker.endpoints)
        _tokens = [join(real, broker, worker) for worker in ("real-1", "real-2")]
        held = [
            session.get(
                keys.lease(f"made-up-{n}"),
                payload=LeaseRequest(worker=f"made-up-{n}").to_bytes(),
                timeout=15.0,
            )
            for n in range(MADE_UP)
        ]
        ok, payload = query(session, keys.STATUS)  # while thousands are held
        assert ok and len(payload) < MAX_MESSAGE_BYTES
        crowded = decode(BrokerStatus, payload)
        assert MAX_LISTED < crowded.worker_count <= MADE_UP + 2
        assert len(crowded.workers) == MAX_LISTED

        answers = [reply for replies in held for reply in replies]
        assert len(answers) == MADE_UP  # every one answered, none dropped
        assert all(
            reply.ok is not None and decode(LeaseReply, reply.ok.payload.to_bytes()).leases == []
            for reply in answers
        )
        farm = status(session)
        assert farm.worker_count == 2
        assert [worker.name for worker in farm.workers] == ["real-1", "real-2"]
        assert farm.rejected == 0
        real.close()


def test_a_farms_capacity_counts_every_worker_not_only_those_listed(
    broker: Broker, session: zenoh.Session, tmp_path
) -> None:
    from gainfarm.analytic.evaluators.farm import FarmClient

    many = MAX_LISTED + 5
    _tokens = [
        session.liveliness().declare_token(keys.alive_worker(f"w{n:04d}")) for n in range(many)
    ]
    wait_for(lambda: broker.queue.worker_count() == many, what="every worker to join")
    with FarmClient(broker.endpoints, "s", tmp_path) as farm:
        assert farm.status().worker_count == many
        assert farm.capacity == many


def test_status_without_a_broker_is_a_clear_error(tmp_path) -> None:
    import subprocess
    import sys

    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "gainfarm.broker",
            "status",
            "--connect",
            f"tcp/127.0.0.1:{free_port()}",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2
    assert run.stderr.startswith("broker: error: --connect: cannot open a Zenoh client session")
    assert len(run.stderr.strip().splitlines()) == 1
