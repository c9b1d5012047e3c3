"""Liveness against workers that hold a run up without lying (issue 28, item 4): a hoarder that
takes batches and runs none, a holder that sits on one, and a silent holder whose results reach
the broker but never the study. Each run reaches the calm run's front (generational NSGA-II is
deterministic given the values it is told), and long before a lease or a deadline runs out."""

import hashlib
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import free_port, spawn_worker, stop_workers
from gainfarm.broker.service import Broker
from gainfarm.schemas import keys
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.mcap_episode import decode_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.wire import Result, WireScores
from tests.helpers import (
    HAND_MADE_SCORES,
    ask_for_work,
    hand_in,
    perfect_log,
    result_for,
    serve_log,
    short_spec,
    wait_for,
)

DIGEST = hashlib.sha256(b"a log its worker keeps").hexdigest()


def join(session: zenoh.Session, broker: Broker, *workers: str) -> list[zenoh.LivelinessToken]:
    """Hold the workers' liveliness tokens, as workers do, until the broker counts them all."""
    tokens = [session.liveliness().declare_token(keys.alive_worker(name)) for name in workers]
    wait_for(lambda: broker.queue.worker_count() == len(workers), what="the broker to see them")
    return tokens


def run_silently(session: zenoh.Session, job_id: str, worker: str = "quiet") -> None:
    """`worker` takes the job and hands its result in to the broker, and sends it nowhere."""
    lease = ask_for_work(session, worker)
    assert lease is not None and lease.job.job_id == job_id
    silent = result_for(
        "s", job_id, worker=worker, lease_id=lease.lease_id, episode_bytes=100, digest=DIGEST
    )
    assert hand_in(session, silent).accepted


def honest_result(
    spec: EpisodeSpec, job_id: str, worker: str, lease_id: str
) -> tuple[Result, bytes]:
    """A well-made log of `spec`, and the Result that tells it truly."""
    content = perfect_log(spec)
    result = result_for(
        "s",
        job_id,
        worker=worker,
        lease_id=lease_id,
        episode_bytes=len(content),
        digest=hashlib.sha256(content).hexdigest(),
        scores=WireScores(**score(decode_episode(content)).model_dump()),
    )
    return result, content


# --- the silent holder, played by hand ---------------------------------------------------------


def test_a_result_the_broker_took_but_that_never_came_is_its_record(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    _tokens = join(session, broker, "quiet", "other")
    with FarmClient(broker.endpoints, "s", tmp_path, keep_logs=False) as farm:
        farm.submit({"j1": short_spec()})
        run_silently(session, "j1")

        [result] = list(farm.results(timeout=10))  # the deadline is 600 s

        assert (result.job_id, result.worker, result.digest) == ("j1", "quiet", DIGEST)
        assert result.status == "ok" and result.attempts == 1
        assert result.scores == Scores.model_validate(HAND_MADE_SCORES.model_dump())
        assert result.log is None  # left with its worker: `fetch` asks it, or runs it again
        assert farm.unheard == 1 and farm.unheard_from == {"quiet"}

        # The silent worker gets none of the study's jobs from now on; the other does.
        farm.submit({"j2": short_spec()})
        assert ask_for_work(session, "quiet") is None
        lease = ask_for_work(session, "other")
        assert lease is not None and lease.job.avoid == ["quiet"]


def test_the_last_worker_is_not_left_out_for_a_result_that_did_not_come(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    _tokens = join(session, broker, "quiet")
    with FarmClient(broker.endpoints, "s", tmp_path, keep_logs=False) as farm:
        farm.submit({"j1": short_spec()})
        run_silently(session, "j1")
        [result] = list(farm.results(timeout=10))
        assert result.worker == "quiet" and farm.unheard_from == frozenset()


def test_a_job_that_wanted_its_log_runs_again_elsewhere_when_its_result_never_comes(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    _tokens = join(session, broker, "quiet", "other")
    spec = short_spec()
    with FarmClient(broker.endpoints, "s", tmp_path) as farm:  # every log comes with its result
        farm.submit({"j": spec})
        run_silently(session, "j")
        assert list(farm.results(timeout=5)) == []  # the record has no log: the job runs again

        assert ask_for_work(session, "quiet") is None
        lease = ask_for_work(session, "other")
        assert lease is not None and lease.job.avoid == ["quiet"]
        result, content = honest_result(spec, "j", "other", lease.lease_id)
        assert hand_in(session, result).accepted
        _served = serve_log(session, "s", "other", content)
        session.put(keys.result("s", "j"), b"", attachment=result.to_bytes())
        [outcome] = list(farm.results(timeout=10))
    assert (outcome.worker, outcome.attempts) == ("other", 2)
    assert outcome.log == tmp_path / "episodes" / "j.mcap" and outcome.log.is_file()


def test_a_result_on_its_way_when_the_broker_is_asked_is_still_the_job_s(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    _tokens = join(session, broker, "slow", "other")
    spec = short_spec()
    with FarmClient(broker.endpoints, "s", tmp_path) as farm:
        farm.submit({"j": spec})
        lease = ask_for_work(session, "slow")
        assert lease is not None
        result, content = honest_result(spec, "j", "slow", lease.lease_id)
        assert hand_in(session, result).accepted
        # The client asks about the job (the broker then forgets its record) before it comes.
        while broker.queue.collect("s", None, 0)[0]:  # reading, not collecting: forgets nothing
            assert list(farm.results(timeout=0.2)) == []
        _served = serve_log(session, "s", "slow", content)
        session.put(keys.result("s", "j"), b"", attachment=result.to_bytes())
        [outcome] = list(farm.results(timeout=10))
        assert (outcome.worker, outcome.attempts) == ("slow", 1)
        assert outcome.log is not None and outcome.log.is_file()
        assert farm.unheard == 0 and farm.unheard_from == frozenset()


# --- rogue worker processes on a real farm -----------------------------------------------------

# Far beyond a run: a job that waited for a lease's expiry, or a result for the client's
# deadline (600 s), would outlast RUN_TIMEOUT.
LEASE_SECONDS = 600.0
RUN_TIMEOUT = 240.0
RUN = ("--pop", "8", "--generations", "3", "--seed", "7", "--duration", "3", "--no-replicate")


def spawn_rogue(kind: str, endpoint: str, name: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "tests.rogue", kind, endpoint, name],
        stdin=subprocess.DEVNULL,
        cwd=Path(__file__).parents[3],
    )


def tune_on_farm(out: Path, rogue: str | None = None) -> tuple[bytes, str, Broker]:
    """`analytic start` on a farm of two honest workers (and `rogue`): front.csv, the run's
    output, and the broker (closed) to read its counters."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Broker([endpoint], lease_seconds=LEASE_SECONDS) as broker:
        workers = [spawn_worker(endpoint, f"honest-{n}") for n in range(2)]
        if rogue is not None:
            workers.append(spawn_rogue(rogue, endpoint, rogue))
        try:
            wait_for(lambda: broker.queue.worker_count() == len(workers), 30, "the workers")
            command = ["start", *RUN, "--connect", endpoint, "--out", str(out)]
            ran = subprocess.run(
                [sys.executable, "-m", "gainfarm.analytic", *command],
                capture_output=True,
                text=True,
                timeout=RUN_TIMEOUT,
            )
        finally:
            stop_workers(workers)
    assert ran.returncode == 0, ran.stderr
    return (out / "front.csv").read_bytes(), ran.stdout + ran.stderr, broker


@pytest.fixture(scope="module")
def calm_front(tmp_path_factory: pytest.TempPathFactory) -> Iterator[bytes]:
    front, _, _ = tune_on_farm(tmp_path_factory.mktemp("calm") / "run")
    yield front


@pytest.mark.slow
def test_a_hoarder_asking_for_more_and_more_only_gives_its_batches_back(
    calm_front: bytes, tmp_path: Path
) -> None:
    front, _, broker = tune_on_farm(tmp_path / "run", "hoarder")
    assert broker.queue.abandoned > 0  # it did take batches, and asked past them
    assert front == calm_front


@pytest.mark.slow
def test_a_holder_s_batch_is_run_by_idle_workers_meanwhile(
    calm_front: bytes, tmp_path: Path
) -> None:
    front, _, broker = tune_on_farm(tmp_path / "run", "holder")
    assert broker.queue.copies > 0  # its jobs ran elsewhere, their leases still its own
    assert front == calm_front


@pytest.mark.slow
def test_a_silent_holder_s_results_are_taken_from_the_broker_s_record(
    calm_front: bytes, tmp_path: Path
) -> None:
    front, output, _ = tune_on_farm(tmp_path / "run", "silent")
    assert "silent handed its result in but never sent it" in output
    assert "silent gets no more of this study's jobs" in output
    assert front == calm_front
