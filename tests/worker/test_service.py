"""The sim-cobot as a farm member: a real `worker start` process, and a worker facing a broker
that talks nonsense."""

import hashlib
import json
import logging
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from gainfarm.analytic.evaluators.local import free_port, spawn_worker
from gainfarm.broker.service import Broker
from gainfarm.edges.parts import fetch_parts
from gainfarm.edges.transport import open_session
from gainfarm.models import plant_preset, robot_of
from gainfarm.schemas import EpisodeSpec, TrajectorySpec, keys
from gainfarm.schemas.mcap_episode import decode_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.wire import (
    MAX_EPISODE_BYTES,
    Job,
    JobStatus,
    Lease,
    LeaseReply,
    LeaseRequest,
    Result,
    Submission,
    SubmitReply,
    Verdict,
    decode,
)
from gainfarm.worker.job import simulate
from gainfarm.worker.service import CobotWorker
from tests.helpers import open_study, query, short_spec, wait_for


class Inbox:
    """Every result published for a study, as (Result, episode bytes)."""

    def __init__(self, session: zenoh.Session, study: str):
        self.received: list[tuple[Result, bytes]] = []
        self._subscriber = session.declare_subscriber(keys.study_results(study), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        result = decode(Result, sample.attachment.to_bytes())
        self.received.append((result, sample.payload.to_bytes()))


def submit(
    session: zenoh.Session, study: str, specs: dict[str, EpisodeSpec], keep_log: bool = True
) -> SubmitReply:
    """Submit jobs as an analytic process does; by default they ask for their logs."""
    jobs = [Job(job_id=job_id, spec=spec, keep_log=keep_log) for job_id, spec in specs.items()]
    ok, payload = query(session, keys.submit(study), Submission(study=study, jobs=jobs).to_bytes())
    assert ok, payload
    reply = decode(SubmitReply, payload)
    assert reply.queued == list(specs), reply
    return reply


def get_log(
    session: zenoh.Session, key: str, payload: bytes | None = None
) -> list[tuple[bool, bytes]]:
    """Every answer to a query on a log key, as (ok, payload): a part, or the reason not."""
    replies = session.get(key, payload=payload, timeout=5.0)
    return [
        (True, reply.ok.payload.to_bytes())
        if reply.ok is not None
        else (False, reply.err.payload.to_bytes())
        for reply in replies
    ]


def fetch_log(session: zenoh.Session, key: str) -> bytes | None:
    """A kept log, fetched in parts as a study fetches it."""
    return fetch_parts(session, key, MAX_EPISODE_BYTES, timeout=5.0)


def spawn(endpoint: str, name: str, *options: str) -> subprocess.Popen:
    """`worker start` as a farm runs it, with `options`."""
    command = [
        sys.executable,
        "-m",
        "gainfarm.worker",
        "start",
        "--connect",
        endpoint,
        "--name",
        name,
    ]
    return subprocess.Popen(
        [*command, "--log-level", "warning", *options], stdin=subprocess.DEVNULL
    )


@pytest.mark.slow
def test_a_worker_process_serves_jobs_and_a_failing_job_does_not_stop_it(
    broker: Broker, session: zenoh.Session
) -> None:
    """No result carries its log, whether its job asks for it or not: the worker keeps every
    log (in the --log-memory it was given, the least allowed) and serves it in parts."""
    inbox = Inbox(session, "s")
    _token = open_study(session, broker, "s")
    worker = spawn(broker.endpoints[0], "cobot-1", "--log-memory", "16")
    try:
        out_of_reach = short_spec(kind="spiral", duration=3.0, center=(3.0, 0.0, 0.4))
        submit(session, "s", {"far": out_of_reach, "near": short_spec()})
        submit(session, "s", {"kept": short_spec(seed=1)}, keep_log=False)
        wait_for(lambda: len(inbox.received) == 3, timeout=60, what="the results")
        kept, empty = next((r, c) for r, c in inbox.received if r.job_id == "kept")
        fetched = fetch_log(session, keys.log("s", "cobot-1", kept.digest))
        near = next(r for r, _ in inbox.received if r.job_id == "near")
        content = fetch_log(session, keys.log("s", "cobot-1", near.digest))
    finally:
        worker.terminate()
        assert worker.wait(15) == 0
    results = {result.job_id: (result, content) for result, content in inbox.received}
    failed, nothing = results["far"]
    assert failed.status == JobStatus.failed and "reach" in failed.reason and nothing == b""
    assert failed.scores is None
    ran, sent = results["near"]
    assert ran.status == JobStatus.ok and ran.worker == "cobot-1" and sent == b""
    assert content is not None and ran.episode_bytes == len(content)
    assert decode_episode(content).metadata.spec == short_spec()
    assert ran.scores is not None
    assert ran.scores.model_dump() == score(decode_episode(content)).model_dump()
    assert kept.status == JobStatus.ok and empty == b""
    assert fetched is not None and hashlib.sha256(fetched).hexdigest() == kept.digest
    assert decode_episode(fetched).metadata.spec == short_spec(seed=1)
    assert broker.queue.jobs_done == 3


@pytest.mark.slow
def test_a_worker_serves_a_six_joint_arm_and_refuses_an_arm_it_lacks(
    broker: Broker, session: zenoh.Session
) -> None:
    """Over real Zenoh, a real `worker start`: a UR5e job runs (its log names the UR5e's six
    joints); a job on an arm this installation lacks, and one whose gains miscount its arm's
    joints, are refused with the reason, and the worker goes on serving."""
    inbox = Inbox(session, "s")
    _token = open_study(session, broker, "s")
    worker = spawn(broker.endpoints[0], "cobot-arms")
    ur5e = robot_of("ur5e")
    six = EpisodeSpec(
        gains=ur5e.default_gains,
        trajectory=TrajectorySpec(kind="fourier", duration=0.5),
        plant=plant_preset("realistic", "ur5e"),
    )
    try:
        submit(
            session,
            "s",
            {
                "nowhere": six.model_copy(update={"plant": PlantSpec(robot="nosucharm")}),
                "miscounted": six.model_copy(update={"gains": short_spec().gains}),
                "ur5e": six,
            },
        )
        wait_for(lambda: len(inbox.received) == 3, timeout=60, what="the results")
        ran = next(result for result, _ in inbox.received if result.job_id == "ur5e")
        content = fetch_log(session, keys.log("s", "cobot-arms", ran.digest))
    finally:
        worker.terminate()
        assert worker.wait(15) == 0
    results = {result.job_id: result for result, _ in inbox.received}
    nowhere, miscounted = results["nowhere"], results["miscounted"]
    assert nowhere.status == JobStatus.refused and "'nosucharm'" in nowhere.reason
    assert "gainfarm.robots" in nowhere.reason
    assert miscounted.status == JobStatus.refused
    assert "gains: 7 Kp/Kd pairs for ur5e's 6 joints" in miscounted.reason
    assert ran.status == JobStatus.ok and ran.worker == "cobot-arms" and content is not None
    log = decode_episode(content)
    assert log.metadata.joint_names == ur5e.joint_names and log.q.shape[1] == 6
    assert ran.scores is not None and ran.scores.model_dump() == score(log).model_dump()


def _zenoh_shared_memory() -> list[str]:
    """This process's mappings of Zenoh shared-memory segments."""
    maps = Path("/proc/self/maps").read_text().splitlines()
    return [line for line in maps if line.endswith(".zenoh")]


@pytest.mark.slow
def test_workers_that_come_and_go_leave_no_memory_behind_in_the_broker(
    broker: Broker, session: zenoh.Session
) -> None:
    inbox = Inbox(session, "s")
    _token = open_study(session, broker, "s")
    before = _zenoh_shared_memory()
    logs = []
    for index in range(3):
        worker = spawn_worker(broker.endpoints[0], f"passing-{index}")
        submit(session, "s", {f"j{index}": short_spec()})
        done = index + 1
        wait_for(lambda done=done: len(inbox.received) == done, timeout=60, what="the result")
        result = inbox.received[-1][0]
        logs.append(fetch_log(session, keys.log("s", result.worker, result.digest)))
        worker.terminate()
        assert worker.wait(15) == 0
    assert all(log is not None and len(log) > 100_000 for log in logs)  # logs, not crumbs
    assert _zenoh_shared_memory() == before


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_a_worker_waiting_for_work_stops_at_once_on_sigterm() -> None:
    # Its lease request is held by the broker (30 s here): the worker lets it go when told to
    # stop, rather than hearing the signal only once the hold ends.
    with Broker([f"tcp/127.0.0.1:{free_port()}"], hold_seconds=30.0) as broker:
        worker = spawn_worker(broker.endpoints[0], "idle")
        try:
            wait_for(lambda: broker.status().workers, timeout=30, what="the worker to join")
            time.sleep(0.5)  # its first request for work is sent as it joins, and held
            worker.send_signal(signal.SIGTERM)
            assert worker.wait(10) == 0
        finally:
            worker.kill()
            worker.wait()


def test_serve_until_returns_once_stopped_while_its_request_is_held() -> None:
    with (
        Broker([f"tcp/127.0.0.1:{free_port()}"], hold_seconds=30.0) as broker,
        CobotWorker(broker.endpoints, "w") as worker,
    ):
        stop = threading.Event()
        threading.Timer(0.5, stop.set).start()
        started = time.monotonic()
        assert worker.serve_until(stop) == 0
        assert time.monotonic() - started < 10  # not the 30 s hold


@pytest.mark.slow
def test_a_worker_whose_router_has_no_broker_yet_waits_and_says_so() -> None:
    # A router that listens before its broker serves: the worker does not join it until the
    # broker answers (it would ask for work and hear nothing).
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session("router", listen=[endpoint])
    worker = subprocess.Popen(
        [sys.executable, "-m", "gainfarm.worker", "start", "--connect", endpoint, "--name", "w"],
        stdin=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        time.sleep(4.0)  # its imports, then a second and more of quiet retries
        assert worker.poll() is None
        worker.terminate()
        _, stderr = worker.communicate(timeout=15)
    finally:
        worker.kill()
        worker.wait()
        router.close()
    assert worker.returncode == 0
    assert f"no broker serves on {endpoint} yet; retrying every second" in stderr
    assert stderr.count("retrying") == 1


def test_a_worker_tries_to_connect_again_at_once_then_every_second() -> None:
    from gainfarm.worker.commands import QUIET_TRIES, RETRY_SECONDS, retry_pause

    pauses = [retry_pause(tries) for tries in range(10)]
    assert pauses[0] <= 0.1 and pauses == sorted(pauses) and pauses[-1] == RETRY_SECONDS
    assert sum(pauses[: QUIET_TRIES - 1]) < 1.0  # said within a second


def run_worker(*arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "gainfarm.worker", "start", *arguments],
        capture_output=True,
        text=True,
        timeout=60,
    )


@pytest.mark.slow
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


@pytest.mark.slow
def test_bad_names_and_endpoints_are_one_line_errors() -> None:
    for arguments, message in [
        (["--name", "a/b"], "--name: 'a/b' is not 1 to 64 letters, digits"),
        (["--connect", "nonsense"], "worker: error: --connect: bad endpoint: Endpoints must be"),
        (
            ["--connect", "tls/127.0.0.1:1"],
            "worker: error: --connect: tls/127.0.0.1:1: a tls/ endpoint needs TLS credentials",
        ),
        (["--log-memory", "8"], "--log-memory"),
        (["--log-memory", "lots"], "--log-memory"),
        (["--threads", "0"], "--threads"),
        (["--threads", "all"], "--threads"),
    ]:
        run = run_worker(*arguments)
        assert run.returncode == 2
        assert run.stderr.startswith("worker: error: ") and message in run.stderr
        assert len(run.stderr.splitlines()) == 1


SILENCE = b""  # a scripted answer: hold the query and never answer it


class FakeBroker:
    """A broker stand-in that is the router the worker connects to (so the worker trusts its
    answers): it answers lease requests from one script and hand-ins (requests that carry
    results) from another, and collects the results sent to study "s"."""

    def __init__(
        self, leases: list[bytes | None], verdicts: list[bytes | str | None], delay: float = 0.0
    ):
        """A verdict script's str refuses the results with that reason; the scripts' bytes are
        answered as they are, None with an error; past its end, every result is taken. `delay`:
        s before each answer (an impostor's answer, sent at once, comes first)."""
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.delay = delay
        self.session = open_session("router", listen=[self.endpoint])
        self.leases, self.verdicts = leases, verdicts
        self.unanswered: list[zenoh.Query] = []
        self.handed_in: list[Result] = []
        self.results: list[Result] = []
        self._entities = [
            self.session.declare_queryable(keys.LEASE_ANY, self._on_lease),
            self.session.declare_subscriber(
                keys.study_results("s"),
                lambda sample: self.results.append(decode(Result, sample.attachment.to_bytes())),
            ),
        ]

    def close(self) -> None:
        self.session.close()

    def _on_lease(self, query: zenoh.Query) -> None:
        if keys.last_chunk(str(query.key_expr)) != "w":  # e.g. a probe: not for the scripts
            query.reply_err(b"not you")
            return
        request = decode(LeaseRequest, query.payload.to_bytes())
        if not request.results:
            self._answer(query, self.leases.pop(0) if self.leases else LeaseReply().to_bytes())
            return
        self.handed_in += request.results
        script = self.verdicts.pop(0) if self.verdicts else ""
        if isinstance(script, str):  # a verdict on each result: "" takes them
            verdicts = [
                Verdict(job_id=r.job_id, lease_id=r.lease_id, accepted=not script, reason=script)
                for r in request.results
            ]
            script = LeaseReply(verdicts=verdicts).to_bytes()
        self._answer(query, script)

    def _answer(self, query: zenoh.Query, payload: bytes | None) -> None:
        if self.delay and payload is not SILENCE:
            threading.Timer(self.delay, self._reply, (query, payload)).start()
        else:
            self._reply(query, payload)

    def _reply(self, query: zenoh.Query, payload: bytes | None) -> None:
        if payload is SILENCE:
            self.unanswered.append(query)  # held, never answered: the worker's query times out
        elif payload is None:
            query.reply_err(b"go away")
        else:
            query.reply(query.key_expr, payload)


def lease_of(job_id: str) -> LeaseReply:
    job = Job(job_id=job_id, spec=short_spec())
    return LeaseReply(leases=[Lease(lease_id=f"l-{job_id}", study="s", job=job, expires_in=60)])


@pytest.mark.slow
def test_a_worker_shrugs_off_bad_lease_replies(caplog) -> None:
    """A broker stand-in answers the first lease requests with garbage, an error, an unknown
    protocol version and silence, then with a real lease: the worker logs each, keeps asking,
    runs the job, hands it in and sends it."""
    fake = FakeBroker(
        [b"not json", None, b'{"protocol": 99}', SILENCE, lease_of("j").to_bytes()], []
    )
    with (
        caplog.at_level(logging.WARNING, logger="gainfarm.worker"),
        CobotWorker([fake.endpoint], "w") as worker,
    ):
        stop = threading.Event()
        assert worker.serve(stop, max_jobs=1) == 1
    wait_for(lambda: fake.results, what="the result")
    fake.close()
    assert [(result.job_id, result.lease_id) for result in fake.handed_in] == [("j", "l-j")]
    assert fake.results == fake.handed_in  # handed in first, then sent as it was
    assert fake.results[0].status == JobStatus.ok and worker.refused == 0
    assert "not JSON" in caplog.text
    assert "go away" in caplog.text
    assert "protocol version 99" in caplog.text
    assert fake.unanswered and "no broker answered" in caplog.text
    assert "refused a lease request: Timeout" not in caplog.text  # Zenoh's timeout is not a refusal


@pytest.mark.slow
def test_a_result_the_broker_does_not_take_is_not_sent(caplog) -> None:
    """The broker refuses one hand-in with a reason: the worker does not send that result and
    counts it. It answers the next one with an error, then garbles it: the worker hands the same
    result in again (the broker takes a repeated hand-in as the first) until it is taken, then
    sends it, once."""
    verdicts: list[bytes | str | None] = ["the lease went elsewhere", None, b"garbled"]
    jobs = ["refused", "taken"]
    fake = FakeBroker([lease_of(job_id).to_bytes() for job_id in jobs], verdicts)
    with (
        caplog.at_level(logging.WARNING, logger="gainfarm.worker"),
        CobotWorker([fake.endpoint], "w") as worker,
    ):
        assert worker.serve(threading.Event(), max_jobs=1) == 1
    wait_for(lambda: fake.results, what="the result")
    time.sleep(0.2)  # any result wrongly sent would have arrived by now
    fake.close()
    assert [result.job_id for result in fake.handed_in] == ["refused", *["taken"] * 3]
    assert [result.job_id for result in fake.results] == ["taken"]
    assert worker.refused == 1
    assert "the lease went elsewhere" in caplog.text
    assert "go away" in caplog.text
    assert "not JSON" in caplog.text


def test_a_worker_runs_a_batch_and_hands_it_in_at_once() -> None:
    """Leases in a batch are stepped together, on the worker's threads, and handed in with one
    request, in order; each episode's log is the one it makes alone."""
    jobs = ["a", "b", "c"]
    batch = LeaseReply(leases=[lease_of(job_id).leases[0] for job_id in jobs])
    fake = FakeBroker([batch.to_bytes()], [])
    with CobotWorker([fake.endpoint], "w", threads=2) as worker:
        assert worker.serve(threading.Event(), max_jobs=3) == 3
    wait_for(lambda: len(fake.results) == 3, what="the results")
    fake.close()
    assert [r.job_id for r in fake.handed_in] == jobs
    assert sorted(r.job_id for r in fake.results) == jobs
    alone = simulate(short_spec()).digest
    assert {r.digest for r in fake.handed_in} == {alone}


class Impostor:
    """A client of the farm, not its router, that answers every lease request with a made-up
    lease and every hand-in with a refusal, at once."""

    def __init__(self, endpoints: list[str]):
        self.session = open_session("client", connect=endpoints)
        self.asked: list[str] = []
        self._queryable = self.session.declare_queryable(keys.LEASE_ANY, self._lie)
        # Until the router has its queryable, nobody's queries reach it: probe until they do.
        probe = open_session("client", connect=endpoints)
        probes = [keys.lease("probe")]

        def heard() -> bool:
            for key in probes:
                list(probe.get(key, payload=b"probe", target=zenoh.QueryTarget.ALL, timeout=1.0))
            return all(key in self.asked for key in probes)

        wait_for(heard, what="the impostor's queryables to be known")
        probe.close()
        self.asked.clear()

    def _lie(self, query: zenoh.Query) -> None:
        self.asked.append(str(query.key_expr))
        try:  # the probe's payload is no lease request: nothing handed in
            handed_in = json.loads(query.payload.to_bytes()) if query.payload is not None else []
        except ValueError:
            handed_in = []
        refusals = [
            Verdict(job_id=r["job_id"], lease_id=r["lease_id"], accepted=False, reason="no")
            for r in (handed_in.get("results", []) if isinstance(handed_in, dict) else [])
        ]
        reply = LeaseReply(leases=lease_of("forged").leases, verdicts=refusals)
        query.reply(query.key_expr, reply.to_bytes())

    def close(self) -> None:
        self.session.close()


def ignored_answers(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith("ignored")]


def test_a_worker_ignores_an_impostor_offering_leases(
    broker: Broker, session: zenoh.Session, caplog
) -> None:
    """While the broker holds the worker's lease request (no work yet), an impostor answers it
    with a made-up lease: the worker ignores it, says so, and runs the job the broker leases."""
    inbox = Inbox(session, "s")
    _token = open_study(session, broker, "s")
    impostor = Impostor(broker.endpoints)
    with (
        caplog.at_level(logging.WARNING, logger="gainfarm.ask"),
        CobotWorker(broker.endpoints, "w") as worker,
    ):
        serving = threading.Thread(target=worker.serve, args=(threading.Event(), 1))
        serving.start()
        wait_for(lambda: keys.lease("w") in impostor.asked, what="the impostor's answer")
        submit(session, "s", {"real": short_spec()})
        serving.join(60)
        assert not serving.is_alive() and worker.jobs_done == 1
        # Awaited before the worker's session closes: a put still on its way when a session
        # closes may go with it (a flake on a loaded machine, the worker's put made).
        # Said if the result never comes: whether the broker took it and the worker sent it.
        took = f"the result (broker took {broker.queue.jobs_done}, worker refused {worker.refused})"
        wait_for(lambda: inbox.received, what=took)
    impostor.close()
    assert [result.job_id for result, _ in inbox.received] == ["real"]
    assert worker.refused == 0 and broker.queue.jobs_done == 1
    ignored = ignored_answers(caplog)
    assert any(keys.lease("w") in message for message in ignored)
    assert all("which is not the broker" in message for message in ignored)


@pytest.mark.slow
def test_a_worker_ignores_an_impostor_refusing_its_result(caplog) -> None:
    """The broker (the worker's router) answers after a while; an impostor answers each lease
    request with a made-up lease and each hand-in with a refusal at once: the worker runs the
    broker's job and, once the broker takes it, sends its result."""
    fake = FakeBroker([lease_of("real").to_bytes()], [], delay=0.3)
    impostor = Impostor([fake.endpoint])
    with (
        caplog.at_level(logging.WARNING, logger="gainfarm.ask"),
        CobotWorker([fake.endpoint], "w") as worker,
    ):
        assert worker.serve(threading.Event(), max_jobs=1) == 1
    wait_for(lambda: fake.results, what="the result")
    impostor.close()
    fake.close()
    assert [result.job_id for result in fake.results] == ["real"]
    assert worker.refused == 0
    assert impostor.asked == [keys.lease("w")] * 2  # the lease request, then the hand-in
    ignored = ignored_answers(caplog)
    assert [message.split()[4] for message in ignored] == [keys.lease("w")] * 2
    assert all("which is not the broker" in message for message in ignored)


def test_a_log_not_sent_is_kept_and_served_to_its_study_alone(
    broker: Broker, session: zenoh.Session
) -> None:
    """A job that does not ask for its log: its result comes with the worker's scores and no
    log; the worker serves the log by its digest to the study, in parts, and an error to any
    other question; then it runs a job that asks for its log, which is kept the same way."""
    inbox = Inbox(session, "s")
    _token = open_study(session, broker, "s")
    with CobotWorker(broker.endpoints, "w") as worker:
        serving = threading.Thread(target=worker.serve, args=(threading.Event(), 2))
        serving.start()
        submit(session, "s", {"kept": short_spec()}, keep_log=False)
        wait_for(lambda: inbox.received, timeout=60, what="the result")
        ((result, payload),) = inbox.received
        assert result.status == JobStatus.ok and payload == b""
        content = fetch_log(session, keys.log("s", "w", result.digest))
        assert content is not None and hashlib.sha256(content).hexdigest() == result.digest
        assert len(content) == result.episode_bytes
        assert result.scores is not None
        assert result.scores.model_dump() == score(decode_episode(content)).model_dump()
        for wrong in (keys.log("t", "w", result.digest), keys.log("s", "w", "0" * 64)):
            ((ok, reason),) = get_log(session, f"{wrong}?part=0")
            assert not ok
            assert reason.decode() == f"no such log: {wrong} (never made, or no longer kept)"
        right = keys.log("s", "w", result.digest)
        for asked, said in [
            ("", "ask for one part at a time (?part=N, from 0)"),
            ("?part=1", "part: no part 1, there are 1"),
            ("?part=-1", "part: not a part number: '-1'"),
        ]:
            ((ok, reason),) = get_log(session, f"{right}{asked}")
            assert not ok and reason.decode() == said
        submit(session, "s", {"sent": short_spec(seed=2)})
        serving.join(60)
        assert not serving.is_alive() and worker.jobs_done == 2
        wait_for(lambda: len(inbox.received) == 2, what="the second result")
        sent, payload = inbox.received[1]
        log = fetch_log(session, keys.log("s", "w", sent.digest))
        assert sent.job_id == "sent" and payload == b""
        assert log is not None and hashlib.sha256(log).hexdigest() == sent.digest
        assert decode_episode(log).metadata.spec == short_spec(seed=2)
        assert sent.scores is not None
        assert sent.scores.model_dump() == score(decode_episode(log)).model_dump()
        assert len(worker.logs) == 2 and worker.logs.bytes == len(content) + len(log)
    assert broker.queue.jobs_done == 2


class StubQuery:
    """A query as the log queryable sees it, for what the wire cannot send it."""

    def __init__(self, key: object, answered: bool = False):
        self.key_expr = key
        self.answered = answered  # its replies fail, as a query already answered does
        self.replies: list[tuple[bool, object]] = []

    def reply(self, key: object, payload: bytes) -> None:
        self._reply(True, payload)

    def reply_err(self, payload: str) -> None:
        self._reply(False, payload)

    def _reply(self, ok: bool, payload: object) -> None:
        if self.answered:
            raise zenoh.ZError("already answered")
        self.replies.append((ok, payload))


class Unprintable:
    def __str__(self) -> str:
        raise RuntimeError("no key")


def test_garbage_on_the_log_queryable_never_takes_the_worker_down(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Wildcards, other workers' keys, huge chunks, parameters and payloads, a store that fails:
    each gets an error reply, never a log, and the worker then runs a job and serves its log."""
    fake = FakeBroker([lease_of("j").to_bytes()], [])
    client = open_session("client", connect=[fake.endpoint])
    probe = keys.log("s", "w", "0" * 64)
    with (
        caplog.at_level(logging.WARNING, logger="gainfarm.worker"),
        CobotWorker([fake.endpoint], "w") as worker,
    ):
        missing = f"no such log: {probe} (never made, or no longer kept)".encode()
        wait_for(lambda: get_log(client, probe) == [(False, missing)], what="the log queryable")
        garbage: list[tuple[str, bytes | None]] = [
            (keys.log("s", "w", "not-a-digest"), None),
            (keys.log("s", "w", "*"), None),
            (keys.log("*", "w", "*"), None),
            (keys.log("s", "*", "*"), None),
            (f"{keys.ROOT}/study/s/log/w/**", None),
            (f"{keys.ROOT}/**", None),
            (keys.log("s" * 300, "w", "d" * 5000), b"\xff" * 100_000),
            (f"{probe}?a=b;;=;c=%00&d", b"garbage"),
        ]
        for key, payload in garbage:
            replies = get_log(client, key, payload)
            assert replies and not any(ok for ok, _ in replies), (key, replies)
            assert b"Timeout" not in [reason for _, reason in replies]  # every one answered
            assert all(len(reason.splitlines()) == 1 for _, reason in replies)

        def broken(study: str, digest: str) -> bytes | None:
            raise RuntimeError("the store broke")

        worker.logs.get = broken  # type: ignore[method-assign]
        ((ok, reason),) = get_log(client, probe)
        assert not ok and reason == b"this worker could not answer the query"
        del worker.logs.get
        # What the wire does not carry: another worker's key, a key that cannot be read, a
        # query whose replies fail. The callback answers what it can and returns.
        other = StubQuery(keys.log("s", "other", "0" * 64))
        worker._on_log_query(other)
        assert other.replies == [(False, f"not a log key of worker w: {other.key_expr}")]
        unreadable, answered = StubQuery(Unprintable()), StubQuery(probe, answered=True)
        worker._on_log_query(unreadable)
        assert unreadable.replies == [(False, "this worker could not answer the query")]
        worker._on_log_query(answered)
        assert answered.replies == []
        assert worker.serve(threading.Event(), max_jobs=1) == 1
        wait_for(lambda: fake.results, what="the result")
        (result,) = fake.results
        content = fetch_log(client, keys.log("s", "w", result.digest))
        assert content is not None and hashlib.sha256(content).hexdigest() == result.digest
    client.close()
    fake.close()
    assert "the store broke" in caplog.text and "no key" in caplog.text


def test_a_copy_beaten_to_its_result_or_an_ended_study_is_said_quietly_and_a_wrong_lease_not() -> (
    None
):
    """The refusals a worker logs at INFO are the broker's own reasons for a result no one is
    at fault for (broker/queue.py's `complete`, run here): a copy of an overdue job whose other
    copy was taken, before and after its study collected it, and a study that ended."""
    from gainfarm.worker.service import _no_ones_fault
    from tests.broker.test_queue import LEASE_SECONDS, hand_in, jobs, make_queue, take

    queue, clock = make_queue("s")
    queue.submit("s", jobs("j1"))
    first = take(queue, "w1")
    clock.advance(LEASE_SECONDS)
    queue.expire()
    second = take(queue, "w2")  # j1 again: w1 is overdue
    assert hand_in(queue, second, "w2") is None  # w2's copy is taken first
    done_already = hand_in(queue, first, "w1")
    queue.confirm("s", ["j1"])  # the study collected w2's
    collected = hand_in(queue, first, "w1")
    assert done_already and _no_ones_fault(done_already), done_already
    assert collected and _no_ones_fault(collected), collected
    ended = queue.complete("gone", "j1", first.lease_id, "w1", "0" * 64)
    assert ended and _no_ones_fault(ended), ended
    queue.submit("s", jobs("j2"))
    third = take(queue, "w1")
    stolen = hand_in(queue, third, "w2")  # a lease handed to another worker: someone's fault
    assert stolen and not _no_ones_fault(stolen), stolen
