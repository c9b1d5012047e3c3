"""The broker on a real Zenoh router: scheduling over the wire, liveliness, bad messages."""

import logging

import pytest
import zenoh

from broker.service import Broker
from schemas import keys
from schemas.transport import open_session
from schemas.wire import (
    PROTOCOL_VERSION,
    BrokerStatus,
    LeaseRequest,
    decode,
)
from tests.helpers import (
    ask_for_work,
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


def test_a_job_is_leased_to_a_free_worker_and_completed_by_its_result(
    broker: Broker, session: zenoh.Session
) -> None:
    token = open_study(session, broker, "s")
    reply = submit(session, "s", {"j1": short_spec()})
    assert reply.queued == ["j1"] and not reply.rejected
    lease = ask_for_work(session, "w")
    assert lease is not None and lease.job.job_id == "j1" and lease.study == "s"
    assert lease.job.spec == short_spec()
    session.put(keys.result("s", "j1"), b"", attachment=result_for("s", "j1").to_bytes())
    wait_for(lambda: broker.queue.jobs_done == 1, what="the result to complete the job")
    farm = status(session)
    assert farm.studies[0].done == 1 and farm.workers[0].jobs_done == 1
    # A second result for the same job is a duplicate: counted once.
    session.put(keys.result("s", "j1"), b"", attachment=result_for("s", "j1").to_bytes())
    assert ask_for_work(session, "w") is None  # also proves the broker still serves
    assert broker.queue.jobs_done == 1
    token.undeclare()


def test_a_free_worker_waits_for_work_and_gets_it_as_soon_as_it_is_submitted(
    broker: Broker, session: zenoh.Session
) -> None:
    _s = open_study(session, broker, "s")
    waiting = session.get(keys.LEASE, payload=LeaseRequest(worker="w").to_bytes(), timeout=5.0)
    wait_for(lambda: status(session).workers, what="the worker's request to be held")
    submit(session, "s", {"j1": short_spec()})
    replies = list(waiting)
    assert len(replies) == 1
    assert decode_lease(replies[0]).job.job_id == "j1"


def decode_lease(reply: zenoh.Reply):
    from schemas.wire import LeaseReply

    return decode(LeaseReply, reply.ok.payload.to_bytes()).lease


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
    from analytic.local import free_port

    with Broker([f"tcp/127.0.0.1:{free_port()}"], lease_seconds=0.2) as broker:
        session = open_session("client", connect=broker.endpoints)
        _token = open_study(session, broker, "s")
        submit(session, "s", {"j1": short_spec()})
        first = ask_for_work(session, "hung")
        second = ask_for_work(session, "other")  # held until the first lease expires
        assert first is not None and second is not None
        assert first.job.job_id == second.job.job_id == "j1"
        assert first.lease_id != second.lease_id
        assert broker.queue.requeued == 1
        session.close()


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


BAD_PAYLOADS = [
    b"{oops",
    b'{"protocol": 99, "worker": "w", "study": "s", "jobs": []}',
    b'{"protocol": %d, "unexpected": true}' % PROTOCOL_VERSION,
    b"x" * (5 * 1024 * 1024),
]


@pytest.mark.parametrize("key", [keys.SUBMIT, keys.LEASE])
@pytest.mark.parametrize("payload", BAD_PAYLOADS, ids=["json", "version", "schema", "oversized"])
def test_a_bad_query_is_refused_with_a_reason_and_the_broker_serves_on(
    broker: Broker, session: zenoh.Session, key: str, payload: bytes, caplog
) -> None:
    with caplog.at_level(logging.WARNING, logger="gainfarm.broker"):
        ok, reason = query(session, key, payload)
    assert not ok
    assert reason.decode() in caplog.text
    assert any(word in reason.decode() for word in ("JSON", "protocol", "Field", "limit"))
    assert status(session).rejected == 1
    _s = open_study(session, broker, "s")
    assert submit(session, "s", {"j": short_spec()}).queued == ["j"]
    assert ask_for_work(session, "w").job.job_id == "j"


@pytest.mark.parametrize(
    "attachment",
    [None, b"nonsense", b'{"protocol": %d, "study": "s"}' % PROTOCOL_VERSION],
    ids=["none", "json", "schema"],
)
def test_a_bad_result_is_ignored_with_a_reason(
    broker: Broker, session: zenoh.Session, attachment: bytes | None, caplog
) -> None:
    _s = open_study(session, broker, "s")
    submit(session, "s", {"j": short_spec()})
    lease = ask_for_work(session, "w")
    with caplog.at_level(logging.WARNING, logger="gainfarm.broker"):
        session.put(keys.result("s", "j"), b"episode?", attachment=attachment)
        wait_for(lambda: broker.rejected == 1, what="the bad result to be rejected")
    assert "ignored a result" in caplog.text
    assert broker.queue.jobs_done == 0
    assert status(session).studies[0].leased == 1  # the lease stands: a real result may come
    session.put(keys.result("s", "j"), b"", attachment=result_for("s", "j").to_bytes())
    wait_for(lambda: broker.queue.jobs_done == 1, what="the good result")
    assert lease is not None


def test_status_without_a_broker_is_a_clear_error(tmp_path) -> None:
    import subprocess
    import sys

    from analytic.local import free_port

    run = subprocess.run(
        [sys.executable, "-m", "broker", "status", "--connect", f"tcp/127.0.0.1:{free_port()}"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2
    assert run.stderr.startswith("broker: error: --connect: cannot open a Zenoh client session")
    assert len(run.stderr.strip().splitlines()) == 1
