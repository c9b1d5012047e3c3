"""A flood of junk on a study's result keys (issue 28): 64 MiB samples without a result, with a
garbage one, with another study's, and well-formed forgeries for the job ids a run is likely to
have pending, each as long as it claims. A real flooder process (tests/analytic/flooder.py), a
real broker, real workers and a real run: the run ends with the calm front, never waits for the
broker, and the results its client holds stay within their budget, every byte let go at the end.
On the secure profile the flooder holds a worker certificate, and no lease. No result carries a
log (logs are fetched in parts), so no session takes a message larger than a wire message and no
client, whether it keeps every log or not, sees the flood: Zenoh drops it on the way."""

import hashlib
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import free_port, spawn_broker, spawn_worker, stop_workers
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.broker.certs import write_dev_credentials
from gainfarm.broker.service import Broker
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.transport import open_session
from gainfarm.models import written_out
from gainfarm.schemas import TrajectorySpec, keys
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.security import TlsIdentity
from tests.helpers import result_for, short_spec, wait_for

MIB = 1024 * 1024
FLOOD_MIB = 64  # each junk sample, as in the red team's attack
# The results a flooded client may hold before the broker confirms them.
HELD_BUDGET = 100 * MIB
TINY = RunConfig(
    pop=6, seed=7, trajectories=(TrajectorySpec(kind="fourier", duration=0.5),), generations=3
)


@pytest.fixture(scope="module")
def calm(tmp_path_factory: pytest.TempPathFactory) -> TuningRun:
    """TINY in this process, without a farm: the front every flooded run must end with."""
    run = TuningRun.create(tmp_path_factory.mktemp("calm") / "calm", TINY)
    run.run(InProcessEvaluator(run.directory))
    return run


@contextmanager
def broker_process(endpoint: str, identity: TlsIdentity | None = None) -> Iterator[None]:
    """`broker start` in a process of its own, as on a farm (not the run's: see docs/security.md
    on a local farm under a flood), answering before the run starts; stopped at the end."""
    tls = ["--tls", str(identity.directory)] if identity else []
    process = spawn_broker(endpoint, *tls)
    try:
        wait_for(lambda: _answers(endpoint, identity), timeout=30, what="the broker")
        yield
    finally:
        process.terminate()
        assert process.wait(15) == 0


def _answers(endpoint: str, identity: TlsIdentity | None) -> bool:
    try:
        with open_session("client", connect=[endpoint], identity=identity) as session:
            query_status(session, timeout=1.0)
    except (ConnectionError, BrokerUnavailable):
        return False
    return True


@contextmanager
def flooding(endpoint: str, study: str, *options: str) -> Iterator[subprocess.Popen]:
    """The flooder, started and seen flooding; stopped (and its count read) at the end."""
    flooder = subprocess.Popen(
        [sys.executable, "-m", "tests.analytic.flooder", endpoint, study, *options],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert flooder.stdout is not None and flooder.stdout.readline() == "flooding\n"
        yield flooder
    finally:
        flooder.terminate()
        try:
            flooder.wait(15)
        except subprocess.TimeoutExpired:
            flooder.kill()
            flooder.wait()


def flooded_run(directory: Path, farm: FarmClient, flooder: subprocess.Popen) -> TuningRun:
    waits: list[str | None] = []
    farm.on_wait = waits.append
    run = TuningRun.create(directory, TINY)
    run.run(farm)
    flooder.terminate()
    out, _ = flooder.communicate(timeout=15)
    put = int(out.split()[-1])
    # The run never took the flood for the broker's silence; what it held stayed within its
    # budget, and was all let go.
    assert put >= 4 and waits == []
    assert 0 < farm.peak_held_bytes <= HELD_BUDGET and farm.held_bytes == 0
    # Zenoh dropped every sample on the way, none reassembled: no junk reached the client (half
    # the flood has no Result, or not one of this study's), and it held only the honest
    # results' attachments.
    assert farm.ignored == 0 and farm.peak_held_bytes < MIB
    print(
        f"{put} x {FLOOD_MIB} MiB put; ignored {farm.ignored}, not waited for "
        f"{farm.duplicates}, not taken {farm.unconfirmed}, not held {farm.dropped}; "
        f"peak held {farm.peak_held_bytes / MIB:.1f} MiB"
    )
    return run


def assert_calm(run: TuningRun, calm: TuningRun) -> None:
    assert run.finished and run.state.evolution.evaluations == calm.state.evolution.evaluations
    assert (run.directory / "front.csv").read_bytes() == (calm.directory / "front.csv").read_bytes()


@pytest.mark.slow
@pytest.mark.parametrize("keep_logs", [True, False], ids=["keep-logs", "no-logs"])
def test_a_run_ends_with_the_calm_front_through_a_flood_of_junk(
    tmp_path: Path, calm: TuningRun, keep_logs: bool
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with broker_process(endpoint):
        workers = [spawn_worker(endpoint, name) for name in ("w1", "w2")]
        try:
            with (
                FarmClient(
                    [endpoint], "flooded", tmp_path, keep_logs=keep_logs, max_held_bytes=HELD_BUDGET
                ) as farm,
                flooding(endpoint, "flooded", "--mib", str(FLOOD_MIB)) as flooder,
            ):
                run = flooded_run(tmp_path / "run", farm, flooder)
        finally:
            stop_workers(workers)
    assert_calm(run, calm)


@pytest.mark.slow
@pytest.mark.parametrize("keep_logs", [True, False], ids=["keep-logs", "no-logs"])
def test_a_worker_certificate_without_a_lease_floods_a_secure_run_in_vain(
    tmp_path: Path, calm: TuningRun, keep_logs: bool
) -> None:
    credentials = tmp_path / "credentials"
    write_dev_credentials(credentials, analytics=("alice",), workers=("cobot-1", "cobot-2", "x"))
    endpoint, tls = f"tls/127.0.0.1:{free_port()}", str(credentials)
    study = "alice.flooded"  # read off `broker status` by anyone on the farm
    alice = TlsIdentity(credentials, "analytic", "alice")
    with broker_process(endpoint, TlsIdentity(credentials, "worker", "cobot-1")):
        workers = [
            spawn_worker(endpoint, name, "warning", "--tls", tls) for name in ("cobot-1", "cobot-2")
        ]
        try:
            with (
                FarmClient(
                    [endpoint],
                    study,
                    tmp_path,
                    identity=alice,
                    keep_logs=keep_logs,
                    max_held_bytes=HELD_BUDGET,
                ) as farm,
                flooding(
                    endpoint, study, "--mib", str(FLOOD_MIB), "--tls", tls, "--name", "x"
                ) as flooder,
            ):
                run = flooded_run(tmp_path / "run", farm, flooder)
        finally:
            stop_workers(workers)
    assert_calm(run, calm)


def test_forged_results_over_the_budget_are_dropped_and_a_dropped_result_comes_again(
    broker: Broker, session: zenoh.Session, tmp_path: Path
) -> None:
    """Deterministic: nothing is confirmed until `results` runs. A forged result fills the
    budget; the next is dropped; so is the honest worker's result, which the broker took: once
    the broker says so and it does not come, the job runs again, no attempt spent, and its log
    is fetched from its worker in parts."""
    first = forged("s", "j", b"forged")
    with FarmClient(broker.endpoints, "s", tmp_path, max_held_bytes=len(first) + 10) as farm:
        farm.submit({"j": short_spec()})
        session.put(keys.result("s", "j"), b"", attachment=first)  # held
        session.put(keys.result("s", "j"), b"", attachment=forged("s", "j", b"other"))  # not
        wait_for(lambda: farm.held_bytes == len(first) and farm.dropped == 1, what="the forgeries")
        # A log with a result is no result: ignored, whatever it claims.
        session.put(keys.result("s", "j"), b"forged", attachment=first)
        wait_for(lambda: farm.ignored == 1, what="the result with a log")
        worker = spawn_worker(broker.endpoints[0], "w")
        try:
            wait_for(lambda: farm.dropped == 2, timeout=60, what="the honest result, dropped")
            assert broker.queue.jobs_done == 1
            [result] = list(farm.results(timeout=60))
        finally:
            stop_workers([worker])
        assert result.status == "ok" and result.worker == "w" and result.attempts == 1
        assert read_episode(result.log).metadata.spec == written_out(short_spec())
        assert broker.queue.jobs_done == 2  # it ran again
        assert farm.unconfirmed == 1 and farm.held_bytes == 0
        assert farm.peak_held_bytes <= len(first) + 10


def forged(study: str, job_id: str, content: bytes) -> bytes:
    """A forged Result's attachment, claiming a log of `content`, padded to be larger than an
    honest one (so a budget it fills holds an honest one once it is let go)."""
    digest = hashlib.sha256(content).hexdigest()
    result = result_for(
        study,
        job_id,
        worker="forger",
        episode_bytes=len(content),
        digest=digest,
        reason="padding " * 200,
    )
    return result.to_bytes()
