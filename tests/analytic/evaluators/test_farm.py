"""The analytic side's client on a real farm: a broker, worker processes, Zenoh on loopback."""

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from gainfarm.analytic.evaluators.batch import run_batch
from gainfarm.analytic.evaluators.evaluator import Wanted
from gainfarm.analytic.evaluators.farm import FarmClient, FarmUnavailable
from gainfarm.analytic.evaluators.local import (
    LocalFarm,
    local_farm,
    spawn_worker,
    stop_workers,
)
from gainfarm.broker.service import Broker
from gainfarm.models import written_out
from gainfarm.models.dynamics import digest, rigid_prior, to_bytes
from gainfarm.schemas import keys
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PLAIN_PLANT, PlantSpec
from gainfarm.schemas.wire import MAX_EPISODE_BYTES, PART_BYTES, Part
from gainfarm.worker.job import simulate
from tests.helpers import (
    SOFT_GAINS,
    TRACKING_GAINS,
    ask_for_work,
    hand_in,
    result_for,
    serve_log,
    short_spec,
    wait_for,
)


@pytest.mark.slow
def test_several_workers_share_a_batch_and_every_episode_is_kept_and_scored(
    tmp_path: Path,
) -> None:
    specs = {f"j{n}": short_spec(duration=1.0 + 0.1 * n) for n in range(8)}
    with local_farm(workers=2) as endpoint, FarmClient([endpoint], "s", tmp_path) as farm:
        farm.submit(specs)
        evaluations = list(farm.results(timeout=120))
        workers = {worker.name: worker.jobs_done for worker in farm.status().workers}
    assert sorted(result.job_id for result in evaluations) == sorted(specs)
    assert [re.sub(r"-[0-9a-f]{8}$", "", name) for name in sorted(workers)] == [
        "local-0",
        "local-1",
    ]
    assert all(workers.values())
    for result in evaluations:
        assert result.status == "ok" and result.attempts == 1
        assert result.log == tmp_path / "episodes" / f"{result.job_id}.mcap"
        log = read_episode(result.log)
        assert log.metadata.spec == written_out(specs[result.job_id])
        assert score(log) == result.scores
    assert not list((tmp_path / "episodes").glob(".*"))  # no temporary files left behind


@pytest.mark.slow
def test_a_local_farm_starts_its_block_with_every_worker_joined(tmp_path: Path) -> None:
    # Else the first worker up takes the whole first batch and the others idle through it.
    with LocalFarm(workers=2) as local, FarmClient([local.ready()], "s", tmp_path) as farm:
        assert sorted(worker.name for worker in farm.status().workers) == sorted(local.names)


@pytest.mark.slow
def test_a_local_farm_takes_jobs_as_soon_as_its_broker_serves(tmp_path: Path) -> None:
    # Its broker and workers start together; the jobs wait in the broker's queue for the
    # workers to join. Stopping begins on a thread of its own, and the block's end waits for it.
    specs = {f"j{n}": short_spec(duration=0.5) for n in range(4)}
    with LocalFarm(workers=2) as local:
        endpoint = local.ready(joined=False)
        with FarmClient([endpoint], "s", tmp_path) as farm:
            farm.submit(specs)
            evaluations = list(farm.results(timeout=120))
        local.stop(wait=False)
    assert sorted(result.job_id for result in evaluations) == sorted(specs)
    assert all(result.status == "ok" for result in evaluations)
    assert all(process.poll() == 0 for process in [local.broker, *local.workers])


@pytest.mark.slow
def test_a_batch_keeps_every_log_even_when_the_workers_keep_them(tmp_path: Path) -> None:
    # The results bring their workers' scores alone; run_batch fetches every log, checks it by
    # its digest and scores it again here, as a batch promises.
    specs = {f"j{n}": short_spec(duration=0.5 + 0.1 * n) for n in range(4)}
    with (
        local_farm(workers=2) as endpoint,
        FarmClient([endpoint], "s", tmp_path, keep_logs=False) as farm,
    ):
        evaluations = run_batch(farm, specs, tmp_path)
    assert [e.job_id for e in evaluations] == list(specs)
    records = json.loads((tmp_path / "evaluations.json").read_text())
    for result, record in zip(evaluations, records, strict=True):
        assert result.log == tmp_path / "episodes" / f"{result.job_id}.mcap"
        assert record["episode"] == f"episodes/{result.job_id}.mcap"
        assert hashlib.sha256(result.log.read_bytes()).hexdigest() == result.digest
        assert score(read_episode(result.log)) == result.scores


@pytest.mark.slow
def test_a_farm_of_its_own_workers_keeps_a_fetched_log_with_the_scores_claimed(
    tmp_path: Path,
) -> None:
    # A trusted client writes the digest's bytes and takes the claimed scores (decoding and
    # scoring its own workers' logs again checks nothing); any other scores the log here. The
    # claim handed over is deliberately false, to tell the two apart.
    spec = short_spec(duration=0.5)
    with local_farm(workers=1) as endpoint:
        for trusted in (True, False):
            directory = tmp_path / str(trusted)
            with FarmClient([endpoint], "s", directory, keep_logs=False, trusted=trusted) as farm:
                farm.submit({"j": spec})
                (result,) = farm.results(timeout=60)
                assert result.scores is not None and result.digest is not None
                claimed = result.scores.model_copy(update={"f_acc": 1.0})
                want = Wanted(spec, result.digest, (result.worker,), claimed)
                got = farm.fetch({"j": want})["j"]
            assert got.log == directory / "episodes" / "j.mcap"
            assert hashlib.sha256(got.log.read_bytes()).hexdigest() == result.digest
            assert got.scores == (claimed if trusted else result.scores)


@pytest.mark.slow
def test_a_worker_killed_mid_job_loses_no_evaluation_and_none_is_counted_twice(
    broker: Broker, tmp_path: Path
) -> None:
    endpoint = broker.endpoints[0]
    workers = [spawn_worker(endpoint, "victim"), spawn_worker(endpoint, "survivor")]
    try:
        with FarmClient([endpoint], "s", tmp_path) as farm:
            wait_for(lambda: len(broker.status().workers) == 2, timeout=30, what="workers")
            # Long enough (about a second of simulation each) to be killed in the middle.
            specs = {f"j{n}": short_spec(duration=50.0 + n) for n in range(4)}
            farm.submit(specs)
            wait_for(lambda: _busy(broker, "victim"), timeout=30, what="the victim to start")
            workers[0].send_signal(signal.SIGKILL)
            evaluations = list(farm.results(timeout=120))
            assert farm.duplicates == 0
    finally:
        stop_workers(workers)
    assert sorted(result.job_id for result in evaluations) == sorted(specs)
    assert all(result.status == "ok" for result in evaluations)
    assert {result.worker for result in evaluations} >= {"survivor"}
    assert broker.queue.requeued >= 1
    assert broker.queue.jobs_done == len(specs)


def _busy(broker: Broker, name: str) -> bool:
    return any(worker.name == name and worker.busy for worker in broker.status().workers)


@pytest.mark.slow
def test_two_analytic_processes_share_the_farm(broker: Broker, tmp_path: Path) -> None:
    endpoint = broker.endpoints[0]
    candidates = tmp_path / "candidates.json"
    candidates.write_text(
        json.dumps([gains.model_dump() for gains in (TRACKING_GAINS, SOFT_GAINS)])
    )
    workers = [spawn_worker(endpoint, f"w{n}") for n in range(2)]
    try:
        command = [
            sys.executable,
            "-m",
            "gainfarm.analytic",
            "batch",
            "--connect",
            endpoint,
            "--gains",
            str(candidates),
            "--trajectory",
            "fourier",
            "--duration",
            "1",
            "--json",
        ]
        runs = [
            subprocess.Popen(
                [*command, "--run-dir", str(tmp_path / name)],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for name in ("a", "b")
        ]
        outputs = [run.communicate(timeout=120) for run in runs]
    finally:
        stop_workers(workers)
    for run, (out, err) in zip(runs, outputs, strict=True):
        assert run.returncode == 0, err
        assert [json.loads(line)["status"] for line in out.splitlines()] == ["ok", "ok"]
    for name in ("a", "b"):
        records = json.loads((tmp_path / name / "evaluations.json").read_text())
        assert [record["job_id"] for record in records] == ["c000-0-fourier", "c001-0-fourier"]
        assert all((tmp_path / name / record["episode"]).is_file() for record in records)
    assert broker.queue.jobs_done == 4


@pytest.mark.slow
def test_a_job_the_broker_lost_is_resubmitted_at_its_deadline(
    broker: Broker, tmp_path: Path
) -> None:
    # The deadline outlasts a fresh worker's first episode (model, reference, log), so that the
    # one resubmission is the lost job's, never a slow episode's.
    with FarmClient(broker.endpoints, "s", tmp_path, deadline=3.0) as farm:
        farm.submit({"j": short_spec()})
        # The broker forgets every job of the study (as if it had restarted)...
        broker.queue.close_study("s")
        broker.queue.open_study("s")
        # ... so only the client's resubmission brings the job to the worker.
        worker = spawn_worker(broker.endpoints[0], "w")
        try:
            [result] = list(farm.results(timeout=60))
        finally:
            stop_workers([worker])
    assert result.status == "ok" and result.attempts == 2


@pytest.mark.slow
def test_a_job_still_queued_at_its_deadline_is_not_another_attempt(
    broker: Broker, tmp_path: Path
) -> None:
    # The deadline outlasts a fresh worker's first episode, which must not count as overdue.
    with FarmClient(broker.endpoints, "s", tmp_path, deadline=1.0, attempts=2) as farm:
        farm.submit({"j": short_spec()})
        assert list(farm.results(timeout=3.5)) == []  # overdue thrice, but the broker has it
        worker = spawn_worker(broker.endpoints[0], "w")
        try:
            [result] = list(farm.results(timeout=60))
        finally:
            stop_workers([worker])
    assert result.status == "ok" and result.attempts == 1


def test_a_job_without_a_result_after_every_attempt_is_reported_lost(
    broker: Broker, tmp_path: Path
) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path, deadline=0.2, attempts=1) as farm:
        farm.submit({"j": short_spec()})
        broker.queue.close_study("s")
        broker.queue.open_study("s")
        [result] = list(farm.results(timeout=10))
    assert result.status == "lost" and result.reason == "no result after 1 attempts"
    assert result.scores is None and result.log is None


@pytest.mark.slow
def test_bad_results_on_the_studys_key_are_ignored_or_reported(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path, deadline=60) as farm:
        farm.submit({"j1": short_spec(), "j2": short_spec(duration=0.6)})
        digest = hashlib.sha256(b"hello").hexdigest()
        forged = result_for("s", "j1", worker="liar", episode_bytes=5, digest=digest)
        session.put(keys.result("s", "j1"), b"", attachment=b"garbage")
        session.put(keys.result("s", "j1"), b"")
        session.put(keys.result("s", "j1"), b"hello", attachment=forged.to_bytes())  # a log
        session.put(
            keys.result("s", "nope"),
            b"",
            attachment=forged.model_copy(update={"job_id": "nope"}).to_bytes(),
        )
        session.put(keys.result("s", "j1"), b"", attachment=forged.to_bytes())
        worker = spawn_worker(broker.endpoints[0], "w")
        try:
            evaluations = {result.job_id: result for result in farm.results(60)}
        finally:
            stop_workers([worker])
        # Garbage and no attachment, and a result that carries a log (none does); a job never
        # submitted; and a result the broker never took, since "liar" held no lease.
        assert farm.ignored == 3 and farm.duplicates >= 1 and farm.unconfirmed == 1
    assert evaluations["j1"].status == "ok" and evaluations["j1"].attempts == 1
    assert evaluations["j1"].worker == "w"
    assert read_episode(tmp_path / "episodes" / "j1.mcap").metadata.spec == written_out(
        short_spec()
    )
    assert evaluations["j2"].status == "ok" and evaluations["j2"].attempts == 1


def test_an_unusable_log_on_the_last_attempt_fails_the_job_with_the_reason(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path, attempts=1) as farm:
        farm.submit({"j": short_spec()})
        # A worker that holds the lease, and sends a broken log: the broker takes it (it cannot
        # read logs), and the analytic finds it unusable.
        lease = ask_for_work(session, "broken")
        assert lease is not None
        digest = hashlib.sha256(b"hello").hexdigest()
        truncated = result_for(
            "s", "j", worker="broken", lease_id=lease.lease_id, episode_bytes=10, digest=digest
        )
        assert hand_in(session, truncated).accepted
        _served = serve_log(session, "s", "broken", b"hello")
        session.put(keys.result("s", "j"), b"", attachment=truncated.to_bytes())
        [result] = list(farm.results(timeout=10))
    assert result.status == "failed" and result.worker == ""
    assert result.reason == "unusable episode log: 5 bytes, not the 10 sent (attempt 1)"
    assert not (tmp_path / "episodes" / "j.mcap").exists()


@pytest.mark.slow
def test_a_diverged_episode_is_an_evaluation_with_penalised_scores(
    broker: Broker, tmp_path: Path
) -> None:
    weak = PDGains(kp=(5,) * 7, kd=(1,) * 7)
    worker = spawn_worker(broker.endpoints[0], "w")
    try:
        with FarmClient(broker.endpoints, "s", tmp_path) as farm:
            falls = short_spec(duration=2.0, gains=weak).model_copy(update={"plant": PLAIN_PLANT})
            farm.submit({"falls": falls})
            [result] = list(farm.results(timeout=60))
    finally:
        stop_workers([worker])
    assert result.status == "diverged" and result.scores.diverged
    assert result.reason and result.log.is_file()


def test_a_study_can_be_open_in_one_process_only(broker: Broker, tmp_path: Path) -> None:
    with (
        FarmClient(broker.endpoints, "s", tmp_path),
        pytest.raises(FarmUnavailable, match="already open"),
    ):
        FarmClient(broker.endpoints, "s", tmp_path)


def test_no_broker_is_a_clear_error(tmp_path: Path) -> None:
    from gainfarm.analytic.evaluators.local import free_port

    with Broker([f"tcp/127.0.0.1:{free_port()}"]) as other:
        endpoint = other.endpoints[0]
    with pytest.raises(ConnectionError, match="cannot open a Zenoh client session"):
        FarmClient([endpoint], "s", tmp_path)


@pytest.mark.slow
def test_batch_command_in_local_mode(tmp_path: Path) -> None:
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "gainfarm.analytic",
            "batch",
            "--local",
            "--workers",
            "2",
            "--trajectory",
            "spiral",
            "--trajectory",
            "random",
            "--duration",
            "3",
            "--run-dir",
            str(tmp_path / "run"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert run.returncode == 0, run.stderr
    records = json.loads((tmp_path / "run" / "evaluations.json").read_text())
    assert [record["status"] for record in records] == ["ok", "ok"]
    assert "c000-1-random" in run.stdout


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ([], "say where the farm is: --connect ENDPOINT or --local"),
        (
            ["--local", "--connect", "tcp/127.0.0.1:7447"],
            "--connect and --local exclude each other",
        ),
        (["--local", "--gains", "missing.json"], "--gains: cannot read 'missing.json'"),
        (
            ["--local", "--duration", "0"],
            "--duration: must be at least 0.1, got 0",
        ),
    ],
)
@pytest.mark.slow
def test_batch_command_refuses_bad_input_in_one_line(
    arguments: list[str], message: str, tmp_path: Path
) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "gainfarm.analytic", "batch", *arguments],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2
    assert run.stderr.startswith("analytic: error: ") and message in run.stderr
    assert len(run.stderr.splitlines()) == 1
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_a_model_handed_to_an_open_client_is_served_to_the_workers(
    broker: Broker, tmp_path: Path
) -> None:
    # An experiment hands a run's model to a client it has already opened
    # (analytic.experiments.runner.serving): the workers must still be able to fetch it.
    raw = to_bytes(rigid_prior(PlantSpec()))
    spec = EpisodeSpec.model_validate({**short_spec().model_dump(), "feedforward": digest(raw)})
    worker = spawn_worker(broker.endpoints[0], "w")
    try:
        with FarmClient(broker.endpoints, "s", tmp_path) as farm:
            farm.models[digest(raw)] = raw
            farm.submit({"j": spec})
            [result] = list(farm.results(timeout=120))
    finally:
        stop_workers([worker])
    assert result.status == "ok", result.reason
    assert read_episode(result.log).metadata.spec.feedforward == digest(raw)


@pytest.mark.slow
def test_a_result_from_a_worker_the_local_farm_did_not_start_is_refused_and_runs_on_its_own(
    broker: Broker, session: zenoh.Session, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Two strangers take a job each and hand their results in to the broker, which takes them:
    one sends its result to the study, the other never does (its result would be taken from the
    broker's record). Both are refused, no attempt spent, and the jobs run on the farm's own."""
    specs = {"j1": short_spec(duration=0.3), "j2": short_spec(duration=0.4)}
    with (
        caplog.at_level("WARNING", logger="gainfarm.analytic"),
        FarmClient(broker.endpoints, "s", tmp_path, own_workers={"mine"}, attempts=1) as farm,
    ):
        farm.submit(specs)
        for stranger, job_id, sends in (("putter", "j1", True), ("silent", "j2", False)):
            lease = ask_for_work(session, stranger)
            assert lease is not None and lease.job.job_id == job_id
            result = result_for("s", job_id, worker=stranger, lease_id=lease.lease_id)
            assert hand_in(session, result).accepted
            if sends:
                session.put(keys.result("s", job_id), b"", attachment=result.to_bytes())
        worker = spawn_worker(broker.endpoints[0], "mine")
        try:
            evaluations = {outcome.job_id: outcome for outcome in farm.results(120)}
        finally:
            stop_workers([worker])
        assert farm.strangers == {"putter", "silent"}
    for job_id in specs:
        assert evaluations[job_id].status == "ok" and evaluations[job_id].worker == "mine"
        assert evaluations[job_id].attempts == 1
    said = sorted(r.getMessage() for r in caplog.records if "did not start" in r.getMessage())
    assert said == [
        f"result from worker {name}, which this local farm did not start: refused"
        for name in ("putter", "silent")
    ]


def lie(total: int, part: int, length: int) -> Callable[[zenoh.Query], None]:
    """A holder that answers every part with `length` bytes, saying part `part` of `total`
    (model_construct: a liar's Part need not be valid)."""
    header = Part.model_construct(total=total, part=part).to_bytes()
    return lambda query: query.reply(query.key_expr, bytes(length), attachment=header)


@pytest.mark.slow
def test_a_log_of_several_parts_comes_whole_and_lying_holders_are_skipped(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    """A long episode's log, larger than a part, fetched with its result (keep_logs) from a real
    worker process, is the log the episode makes; fetched again with holders that lie about
    its total, answer a part out of range or a part of the wrong size, each liar is refused
    and the next holder asked, until the worker that keeps it."""
    spec = short_spec(duration=15.0)
    calm = simulate(spec)
    assert len(calm.content) > PART_BYTES
    liars = {
        "liar-total": lie(MAX_EPISODE_BYTES + 1, 0, PART_BYTES),
        "liar-range": lie(len(calm.content), 9, PART_BYTES),
        "liar-size": lie(len(calm.content), 0, 100),
    }
    asked: list[str] = []

    def liar(name: str) -> Callable[[zenoh.Query], None]:
        def answer(query: zenoh.Query) -> None:
            asked.append(name)
            liars[name](query)

        return answer

    _liars = [
        session.declare_queryable(keys.log("s", name, calm.digest), liar(name)) for name in liars
    ]
    worker = spawn_worker(broker.endpoints[0], "w")
    try:
        with FarmClient(broker.endpoints, "s", tmp_path) as farm:
            farm.submit({"long": spec})
            [result] = list(farm.results(timeout=120))
            assert result.log is not None and result.log.read_bytes() == calm.content
            result.log.unlink()
            holders = (*liars, "w")
            fetched = farm.fetch({"long": Wanted(spec, calm.digest, holders)})["long"]
    finally:
        stop_workers([worker])
    assert asked == list(liars)
    assert fetched.source == "w" and fetched.log.read_bytes() == calm.content
    assert fetched.scores == result.scores
