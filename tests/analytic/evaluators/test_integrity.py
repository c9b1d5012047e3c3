"""Results nobody can forge, answers nobody can fake, a broker whose absence is no verdict: the
analytic's client against an attacker on the same farm (real Zenoh on loopback, real workers)."""

import hashlib
import time
from pathlib import Path

import pytest
import zenoh

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import free_port, spawn_worker, stop_workers
from gainfarm.broker.service import Broker
from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.episode import Scores
from gainfarm.schemas.mcap_episode import decode_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.wire import Rejection, SubmitReply
from tests.helpers import ask_for_work, hand_in, perfect_log, result_for, short_spec, wait_for


def forge(session: zenoh.Session, study: str, job_id: str, content: bytes, **fields) -> None:
    """A Result claiming the log `content`, sent as a worker sends one (without its log)."""
    digest = hashlib.sha256(content).hexdigest()
    result = result_for(study, job_id, episode_bytes=len(content), digest=digest, **fields)
    session.put(keys.result(study, job_id), b"", attachment=result.to_bytes())


@pytest.mark.slow
def test_a_well_made_result_from_anyone_but_the_lease_holder_is_not_counted(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    specs = {f"g0-{i}": short_spec(duration=0.4 + 0.1 * i) for i in range(3)}
    with FarmClient(broker.endpoints, "s", tmp_path, deadline=60) as farm:
        farm.submit(specs)
        # The attacker knows the specs and the study; it forges a perfect score for each job,
        # under a guessed lease id and a real-sounding worker name, before any worker runs.
        for job_id, spec in specs.items():
            forge(session, "s", job_id, perfect_log(spec), worker="w", lease_id="guess")
        wait_for(lambda: farm._inbox.qsize() >= 3, what="the forged results to arrive")
        worker = spawn_worker(broker.endpoints[0], "w")
        try:
            evaluations = list(farm.results(60))
        finally:
            stop_workers([worker])
        assert farm.unconfirmed == 3
    assert sorted(e.job_id for e in evaluations) == sorted(specs)
    for result in evaluations:
        assert result.status == "ok" and result.attempts == 1
        assert result.scores is not None and result.scores.f_acc > 0
        assert result.scores.f_acc != score_of(perfect_log(result.spec)).f_acc


def score_of(content: bytes) -> Scores:
    return score(decode_episode(content))


def test_a_worker_cannot_hand_in_a_job_leased_to_another(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path) as farm:
        farm.submit({"j": short_spec()})
        lease = ask_for_work(session, "honest")
        assert lease is not None
        content = perfect_log(short_spec())
        digest = hashlib.sha256(content).hexdigest()
        # The thief copies the honest worker's lease id (say it read it off the wire).
        stolen = result_for("s", "j", worker="thief", lease_id=lease.lease_id, digest=digest)
        verdict = hand_in(session, stolen.model_copy(update={"episode_bytes": len(content)}))
        assert not verdict.accepted and "another worker" in verdict.reason
        assert not hand_in(
            session, result_for("s", "j", worker="thief", lease_id="made-up")
        ).accepted
        assert [s.leased for s in broker.status().studies] == [1]
    farm.cancel(["j"])


@pytest.mark.slow
def test_answers_from_anyone_but_the_broker_are_ignored(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    """A fake submit service answering "rejected" to everything (attempt 8)."""

    def reject(query: zenoh.Query) -> None:
        reply = SubmitReply(
            study="s", rejected=[Rejection(job_id="j", reason="rejected by an impostor")]
        )
        query.reply(query.key_expr, reply.to_bytes())
        query.drop()

    impostor = session.declare_queryable(keys.SUBMIT_ANY, reject)
    worker = spawn_worker(broker.endpoints[0], "w")
    try:
        with FarmClient(broker.endpoints, "s", tmp_path) as farm:
            farm.submit({"j": short_spec()})
            [result] = list(farm.results(60))
    finally:
        stop_workers([worker])
        impostor.undeclare()
    assert result.status == "ok" and result.worker == "w"


@pytest.mark.slow
def test_a_result_message_built_to_crash_its_decoder_leaves_the_client_serving(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    worker = spawn_worker(broker.endpoints[0], "w")
    try:
        with FarmClient(broker.endpoints, "s", tmp_path) as farm:
            # Not dropped on the way, however busy the machine (a put's default is to drop).
            block = zenoh.CongestionControl.BLOCK
            session.put(
                keys.result("s", "x"), b"", attachment=b"[" * 100_000, congestion_control=block
            )
            session.put(
                keys.result("s", "y"), b"", attachment=b'{"a":' * 100_000, congestion_control=block
            )
            farm.submit({"j": short_spec()})
            [result] = list(farm.results(60))
            # The worker's result may overtake the junk (another publisher): each is counted
            # as it is read, on Zenoh's thread.
            deadline = time.monotonic() + 30
            while farm.ignored < 2 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert farm.ignored == 2
    finally:
        stop_workers([worker])
    assert result.status == "ok"


@pytest.mark.slow
def test_a_broker_that_moved_away_leaves_the_run_waiting_not_failing(tmp_path: Path) -> None:
    """The broker is killed and a new one starts on another port (attempt 12): the client can
    no longer reach it, so no job's attempts are spent; it waits, and says why."""
    first = Broker([f"tcp/127.0.0.1:{free_port()}"])
    try:
        farm = FarmClient(first.endpoints, "s", tmp_path, deadline=1.0, attempts=1)
        farm.submit({"j": short_spec()})
    finally:
        first.close()
    told: list[str | None] = []
    farm.on_wait = told.append
    with Broker([f"tcp/127.0.0.1:{free_port()}"]), farm:
        assert list(farm.results(timeout=5)) == []
        assert farm.pending == 1 and farm.waiting is not None
        assert told == [farm.waiting]  # said once, for the progress line


@pytest.mark.slow
def test_a_broker_that_comes_back_gets_the_pending_jobs_again(tmp_path: Path) -> None:
    port = free_port()
    first = Broker([f"tcp/127.0.0.1:{port}"])
    try:
        farm = FarmClient(first.endpoints, "s", tmp_path, deadline=30.0, attempts=1)
        farm.submit({"j": short_spec()})
    finally:
        first.close()
    with farm:
        assert list(farm.results(timeout=3)) == []
        assert farm.waiting is not None
        with Broker([f"tcp/127.0.0.1:{port}"]) as second:
            worker = spawn_worker(second.endpoints[0], "w")
            try:
                [result] = list(farm.results(timeout=60))
            finally:
                stop_workers([worker])
    assert result.status == "ok" and result.attempts == 1
    assert farm.waiting is None


def test_status_from_an_impostor_is_not_believed(broker: Broker, tmp_path: Path) -> None:
    impostor = open_session("client", connect=broker.endpoints)
    fake = impostor.declare_queryable(
        keys.STATUS, lambda query: (query.reply(query.key_expr, b"{}"), query.drop())
    )
    try:
        with FarmClient(broker.endpoints, "s", tmp_path) as farm:
            status = farm.status()
        assert [study.name for study in status.studies] == ["s"]
    finally:
        fake.undeclare()
        impostor.close()
