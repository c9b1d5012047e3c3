"""The secure profile: TLS with mutual authentication, and each role kept to its own keys.

Every session here is real: a TLS router with the access policy, clients holding certificates
from the farm's CA (or from another one), and a real worker process."""

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from analytic.farm import FarmClient
from analytic.local import free_port
from broker.certs import write_dev_credentials
from broker.service import Broker
from schemas import keys
from schemas.security import Role, TlsIdentity
from schemas.transport import open_session
from schemas.wire import Job, JobStatus, LeaseRequest, Submission
from tests.helpers import open_studies, result_for, short_spec, wait_for

DENIED_SECONDS = 1.0  # a denied query is dropped, not refused: wait this long for no answer


@pytest.fixture(scope="module")
def credentials(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("credentials")
    write_dev_credentials(directory, ("localhost", "127.0.0.1"))
    return directory


@pytest.fixture
def secure_broker(credentials: Path) -> Iterator[Broker]:
    endpoint = f"tls/127.0.0.1:{free_port()}"
    with Broker([endpoint], lease_seconds=30.0, identity=TlsIdentity(credentials, "broker")) as b:
        yield b


@pytest.fixture
def sessions(secure_broker: Broker, credentials: Path) -> Iterator[dict[Role, zenoh.Session]]:
    """One client session per role, each with its own certificate."""
    opened = {
        role: open_session(
            "client", connect=secure_broker.endpoints, identity=TlsIdentity(credentials, role)
        )
        for role in ("analytic", "worker")
    }
    yield opened
    for session in opened.values():
        session.close()


def _analytic(broker: Broker, credentials: Path, study: str) -> FarmClient:
    """An analytic process's client on the secure farm, with the analytic credentials."""
    identity = TlsIdentity(credentials, "analytic")
    return FarmClient(broker.endpoints, study, credentials / study, identity=identity)


def _queued(broker: Broker, study: str) -> int:
    return sum(state.queued for state in broker.queue.study_states() if state.name == study)


def _workers(broker: Broker) -> list[str]:
    return [worker.name for worker in broker.queue.worker_states()]


def _tls_client(endpoint: str, identity: TlsIdentity, present_certificate: bool) -> zenoh.Config:
    """A client configuration by hand, since open_session always presents a certificate."""
    tls = identity.zenoh_tls(listening=False)
    if not present_certificate:
        tls = {"root_ca_certificate": tls["root_ca_certificate"]}
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/link/tls", json.dumps(tls))
    return config


def _answers(session: zenoh.Session, key: str, payload: bytes) -> list[bytes]:
    replies = session.get(key, payload=payload, timeout=DENIED_SECONDS)
    return [reply.ok.payload.to_bytes() for reply in replies if reply.ok is not None]


def test_a_secure_farm_runs_jobs_end_to_end(secure_broker: Broker, credentials: Path) -> None:
    endpoint, tls = secure_broker.endpoints[0], str(credentials)
    command = [sys.executable, "-m", "worker", "start", "--connect", endpoint, "--tls", tls]
    worker = subprocess.Popen([*command, "--name", "secure-1", "--log-level", "warning"])
    try:
        with _analytic(secure_broker, credentials, "secure") as farm:
            farm.submit({"a": short_spec(), "b": short_spec(duration=0.3)})
            evaluations = list(farm.results(timeout=60))
    finally:
        worker.terminate()
        assert worker.wait(15) == 0
    assert sorted(e.job_id for e in evaluations) == ["a", "b"]
    assert all(e.status == JobStatus.ok and e.worker == "secure-1" for e in evaluations)
    done = subprocess.run(
        [sys.executable, "-m", "broker", "status", "--json", "--connect", endpoint, "--tls", tls],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["jobs_done"] == 2


def test_a_client_without_a_certificate_from_the_farms_ca_cannot_connect(
    secure_broker: Broker, credentials: Path, tmp_path: Path
) -> None:
    endpoint = secure_broker.endpoints[0]
    write_dev_credentials(tmp_path, ("localhost", "127.0.0.1"))  # another CA, same role names
    with pytest.raises(ConnectionError):
        open_session("client", connect=[endpoint], identity=TlsIdentity(tmp_path, "analytic"))
    # The farm's CA, so the client trusts the broker, but no certificate of its own to show.
    identity = TlsIdentity(credentials, "analytic")
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(_tls_client(endpoint, identity, present_certificate=False))
    zenoh.open(_tls_client(endpoint, identity, present_certificate=True)).close()  # the control
    plain = endpoint.replace("tls/", "tcp/")
    with pytest.raises(ConnectionError):
        open_session("client", connect=[plain])
    assert _workers(secure_broker) == []


def test_a_worker_identity_cannot_publish_jobs(
    secure_broker: Broker, sessions: dict[Role, zenoh.Session]
) -> None:
    _token = sessions["analytic"].liveliness().declare_token(keys.alive_study("s"))
    wait_for(lambda: "s" in open_studies(secure_broker.queue), what="the broker to open the study")
    forged = Submission(study="s", jobs=[Job(job_id="forged", spec=short_spec())])
    assert _answers(sessions["worker"], keys.SUBMIT, forged.to_bytes()) == []
    # The same submission from the analytic identity is answered and queued.
    assert len(_answers(sessions["analytic"], keys.SUBMIT, forged.to_bytes())) == 1
    wait_for(lambda: _queued(secure_broker, "s") == 1, what="the analytic's job")


def test_an_analytic_identity_cannot_pose_as_a_worker(
    secure_broker: Broker, sessions: dict[Role, zenoh.Session], credentials: Path
) -> None:
    analytic = sessions["analytic"]
    with _analytic(secure_broker, credentials, "s") as farm:
        farm.submit({"j": short_spec()})
        wait_for(lambda: _queued(secure_broker, "s") == 1, what="the job to queue")
        # It cannot take the job, register as a worker, or slip a result in.
        request = LeaseRequest(worker="impostor").to_bytes()
        assert _answers(analytic, keys.LEASE, request) == []
        _token = analytic.liveliness().declare_token(keys.alive_worker("impostor"))
        forged = result_for("s", "j", worker="impostor", status=JobStatus.failed)
        analytic.put(keys.result("s", "j"), b"", attachment=forged.to_bytes())
        assert list(farm.results(timeout=2.0)) == []
        assert _queued(secure_broker, "s") == 1
        assert "impostor" not in _workers(secure_broker)
        # A real worker identity can: it leases the job and its result reaches the client.
        lease = _answers(sessions["worker"], keys.LEASE, LeaseRequest(worker="real").to_bytes())
        assert len(lease) == 1 and b'"job_id":"j"' in lease[0]
