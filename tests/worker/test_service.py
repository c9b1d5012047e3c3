"""The sim-cobot as a farm member: a real `worker start` process, and a worker facing a broker
that talks nonsense."""

import logging
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import zenoh

from analytic.local import free_port, spawn_worker
from broker.service import Broker
from schemas import keys
from schemas.mcap_episode import decode_episode
from schemas.transport import open_session
from schemas.wire import JobStatus, Lease, LeaseReply, Result, decode
from tests.helpers import open_study, short_spec, submit, wait_for
from worker.service import CobotWorker


class Inbox:
    """Every result published for a study, as (Result, episode bytes)."""

    def __init__(self, session: zenoh.Session, study: str):
        self.received: list[tuple[Result, bytes]] = []
        self._subscriber = session.declare_subscriber(keys.study_results(study), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        result = decode(Result, sample.attachment.to_bytes())
        self.received.append((result, sample.payload.to_bytes()))


def test_a_worker_process_serves_jobs_and_a_failing_job_does_not_stop_it(
    broker: Broker, session: zenoh.Session
) -> None:
    inbox = Inbox(session, "s")
    _token = open_study(session, broker, "s")
    worker = spawn_worker(broker.endpoints[0], "cobot-1")
    try:
        out_of_reach = short_spec(center=(3.0, 0.0, 0.4))
        submit(session, "s", {"far": out_of_reach, "near": short_spec()})
        wait_for(lambda: len(inbox.received) == 2, timeout=60, what="both results")
    finally:
        worker.terminate()
        assert worker.wait(15) == 0
    results = {result.job_id: (result, content) for result, content in inbox.received}
    failed, nothing = results["far"]
    assert failed.status == JobStatus.failed and "reach" in failed.reason and nothing == b""
    ran, content = results["near"]
    assert ran.status == JobStatus.ok and ran.worker == "cobot-1"
    assert ran.episode_bytes == len(content)
    assert decode_episode(content).metadata.spec == short_spec()
    assert broker.queue.jobs_done == 2


def _zenoh_shared_memory() -> list[str]:
    """This process's mappings of Zenoh shared-memory segments."""
    maps = Path("/proc/self/maps").read_text().splitlines()
    return [line for line in maps if line.endswith(".zenoh")]


def test_workers_that_come_and_go_leave_no_memory_behind_in_the_broker(
    broker: Broker, session: zenoh.Session
) -> None:
    inbox = Inbox(session, "s")
    _token = open_study(session, broker, "s")
    before = _zenoh_shared_memory()
    for index in range(3):
        worker = spawn_worker(broker.endpoints[0], f"passing-{index}")
        submit(session, "s", {f"j{index}": short_spec()})
        done = index + 1
        wait_for(lambda done=done: len(inbox.received) == done, timeout=60, what="the result")
        worker.terminate()
        assert worker.wait(15) == 0
    assert all(len(content) > 100_000 for _, content in inbox.received)  # logs, not crumbs
    assert _zenoh_shared_memory() == before


def test_sigterm_mid_job_finishes_and_returns_the_job_then_exits(
    broker: Broker, session: zenoh.Session
) -> None:
    inbox = Inbox(session, "s")
    _token = open_study(session, broker, "s")
    worker = spawn_worker(broker.endpoints[0], "cobot-1")
    wait_for(lambda: broker.status().workers, timeout=30, what="the worker to join")
    submit(session, "s", {"long": short_spec(duration=60.0)})  # about a second of simulation
    wait_for(lambda: broker.status().workers[0].busy, timeout=30, what="the worker to start")
    worker.send_signal(signal.SIGTERM)
    assert worker.wait(30) == 0
    assert [result.job_id for result, _ in inbox.received] == ["long"]
    assert inbox.received[0][0].status == JobStatus.ok
    wait_for(lambda: not broker.status().workers, what="the worker's token to go")


def test_a_worker_started_before_its_broker_waits_for_it() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    worker = spawn_worker(endpoint, "early", log_level="info")
    try:
        time.sleep(1.5)
        assert worker.poll() is None
        with Broker([endpoint]) as broker:
            wait_for(lambda: broker.status().workers, timeout=30, what="the worker to join")
    finally:
        worker.terminate()
        assert worker.wait(15) == 0


def run_worker(*arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "worker", "start", *arguments],
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_a_second_worker_with_a_taken_name_is_refused(broker: Broker) -> None:
    first = spawn_worker(broker.endpoints[0], "twin")
    try:
        wait_for(lambda: broker.status().workers, timeout=30, what="the first twin")
        second = run_worker("--connect", broker.endpoints[0], "--name", "twin")
    finally:
        first.terminate()
        first.wait(15)
    assert second.returncode == 2
    assert (
        second.stderr == "worker: error: a worker named 'twin' is already connected to this farm\n"
    )


def test_bad_names_and_endpoints_are_one_line_errors() -> None:
    for arguments, message in [
        (["--name", "a/b"], "--name: 'a/b' is not 1 to 64 letters, digits"),
        (["--connect", "nonsense"], "bad endpoint"),
    ]:
        run = run_worker(*arguments)
        assert run.returncode == 2
        assert run.stderr.startswith("worker: error: ") and message in run.stderr
        assert len(run.stderr.splitlines()) == 1


def test_a_worker_shrugs_off_bad_lease_replies(caplog) -> None:
    """A broker stand-in answers the first lease requests with garbage, an error, an unknown
    protocol version and silence, then with a real lease: the worker logs each, keeps asking,
    runs the job."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fake = open_session("router", listen=[endpoint])
    lease = Lease(
        lease_id="l1", study="s", job={"job_id": "j", "spec": short_spec()}, expires_in=60
    )
    silence = b""
    answers = [b"not json", None, b'{"protocol": 7}', silence, LeaseReply(lease=lease).to_bytes()]
    results: list[Result] = []
    unanswered: list[zenoh.Query] = []

    def answer(query: zenoh.Query) -> None:
        payload = answers.pop(0) if answers else LeaseReply().to_bytes()
        if payload is silence:
            unanswered.append(query)  # held, never answered: the worker's query times out
        elif payload is None:
            query.reply_err(b"go away")
        else:
            query.reply(keys.LEASE, payload)

    _queryable = fake.declare_queryable(keys.LEASE, answer)
    _subscriber = fake.declare_subscriber(
        keys.study_results("s"),
        lambda sample: results.append(decode(Result, sample.attachment.to_bytes())),
    )
    with (
        caplog.at_level(logging.WARNING, logger="gainfarm.worker"),
        CobotWorker([endpoint], "w") as worker,
    ):
        stop = threading.Event()
        worker.serve(stop, max_jobs=1)
    fake.close()
    wait_for(lambda: results, what="the result")
    assert results[0].job_id == "j" and results[0].status == JobStatus.ok
    assert "not JSON" in caplog.text
    assert "go away" in caplog.text
    assert "protocol version 7" in caplog.text
    assert unanswered and "no broker answered" in caplog.text
    assert "refused a lease request: Timeout" not in caplog.text  # Zenoh's timeout is not a refusal
