"""The secure profile: TLS with mutual authentication, and each participant kept to the keys of
its own name.

Every session here is real: a TLS router with the access policy built from its credentials
directory, and clients holding certificates from the farm's CA (or from another CA, or revoked).
The router's own queryables stand in for the broker's services, as the broker's run on its router
session, which the access control does not filter: so the policy is tested by itself, on the key
space of schemas/keys.py. The last test runs a real broker and a real worker process."""

import hashlib
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.certs import revoke, write_dev_credentials
from gainfarm.broker.service import Broker
from gainfarm.edges.transport import open_session
from gainfarm.models.dynamics import digest, rigid_prior, to_bytes
from gainfarm.schemas import keys
from gainfarm.schemas.robot import IDEAL_PLANT
from gainfarm.schemas.security import Role, TlsIdentity
from gainfarm.schemas.wire import JobStatus
from tests.helpers import hand_in, perfect_log, result_for, short_spec, wait_for

DENIED_SECONDS = 1.0  # a denied query is dropped, not refused: wait this long for no answer
SERVICES = [keys.SUBMIT_ANY, keys.CONFIRM_ANY, keys.LEASE_ANY, keys.STATUS]


@pytest.fixture(scope="module")
def credentials(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The broker's directory: alice, bob, mallory (revoked below), workers cobot-1 and -2."""
    directory = tmp_path_factory.mktemp("credentials")
    write_dev_credentials(
        directory, analytics=("alice", "bob", "mallory"), workers=("cobot-1", "cobot-2")
    )
    return directory


@pytest.fixture(scope="module")
def stolen(credentials: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Mallory's own copy of her credentials, kept after the site revoked her."""
    directory = tmp_path_factory.mktemp("stolen")
    for name in ("ca.pem", "analytic.mallory.pem", "analytic.mallory.key"):
        shutil.copy(credentials / name, directory / name)
    revoke(credentials, "mallory")
    return directory


@dataclass
class Router:
    session: zenoh.Session
    endpoint: str
    results: list[str] = field(default_factory=list)  # result keys that reached the router
    entities: list[object] = field(default_factory=list)  # kept: Zenoh undeclares the collected

    def tokens(self) -> set[str]:
        """The liveliness tokens the router sees now."""
        replies = self.session.liveliness().get(f"{keys.ROOT}/alive/**", timeout=0.5)
        return {str(reply.ok.key_expr) for reply in replies if reply.ok is not None}


@pytest.fixture
def router(credentials: Path, stolen: Path) -> Iterator[Router]:
    """A secure router, after mallory's revocation, answering every broker service."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    session = open_session("router", listen=[endpoint], identity=TlsIdentity(credentials, "broker"))
    running = Router(session, endpoint)
    running.entities = [
        session.declare_queryable(key, lambda query: query.reply(query.key_expr, b"ok"))
        for key in SERVICES
    ]
    running.entities.append(
        session.declare_subscriber(
            keys.ALL_RESULTS, lambda sample: running.results.append(str(sample.key_expr))
        )
    )
    yield running
    session.close()


@pytest.fixture
def connect(router: Router) -> Iterator[Callable[..., zenoh.Session]]:
    """Open client sessions to the router as `role` `name` (from DIR), closed after the test."""
    opened: list[zenoh.Session] = []

    def client(directory: Path, role: Role, name: str) -> zenoh.Session:
        identity = TlsIdentity(directory, role, name)
        opened.append(open_session("client", connect=[router.endpoint], identity=identity))
        return opened[-1]

    yield client
    for session in opened:
        session.close()


def _answered(session: zenoh.Session, queried: list[str]) -> set[str]:
    """Which of the keys queried were answered (all in flight at once, to wait only once)."""
    pending = {key: session.get(key, payload=b"{}", timeout=DENIED_SECONDS) for key in queried}
    return {key for key, replies in pending.items() if any(r.ok is not None for r in replies)}


def _collect(session: zenoh.Session, key: str, into: list[str]) -> zenoh.Subscriber:
    return session.declare_subscriber(key, lambda sample: into.append(str(sample.key_expr)))


def test_a_worker_leases_and_hands_in_only_under_its_own_name(
    router: Router, connect: Callable[..., zenoh.Session], credentials: Path
) -> None:
    worker = connect(credentials, "worker", "cobot-1")
    allowed = [keys.lease("cobot-1"), keys.STATUS]
    squatting = [keys.lease("cobot-2"), keys.LEASE_ANY]
    not_its_job = [keys.submit("alice.x"), keys.confirm("alice.x"), keys.lease("cobot-1.x")]
    assert _answered(worker, allowed + squatting + not_its_job) == set(allowed)

    _denied = worker.liveliness().declare_token(keys.alive_worker("cobot-2"))
    _token = worker.liveliness().declare_token(keys.alive_worker("cobot-1"))
    wait_for(lambda: keys.alive_worker("cobot-1") in router.tokens(), what="cobot-1's token")
    assert keys.alive_worker("cobot-2") not in router.tokens()
    # A result may go to any study: the broker hands on only those whose lease it holds.
    worker.put(keys.result("alice.x", "j1"), b"")
    wait_for(lambda: router.results == [keys.result("alice.x", "j1")], what="the result")


def test_an_analytic_participant_uses_only_studies_it_owns(
    router: Router, connect: Callable[..., zenoh.Session], credentials: Path
) -> None:
    alice = connect(credentials, "analytic", "alice")
    allowed = [keys.submit("alice.x"), keys.confirm("alice.run-ab12"), keys.STATUS]
    bobs = [keys.submit("bob.x"), keys.confirm("bob.x"), keys.submit("alice")]
    wildcards = [keys.SUBMIT_ANY, keys.submit("**"), keys.CONFIRM_ANY]
    not_its_job = [keys.lease("cobot-1")]
    assert _answered(alice, allowed + bobs + wildcards + not_its_job) == set(allowed)

    # Subscribing to bob's results, or to everyone's, is refused; so bob's results never reach
    # alice's session (a second session of hers, since a session hands every sample it does
    # receive to all of its matching subscribers).
    prying = connect(credentials, "analytic", "alice")
    pried: list[str] = []
    _prying = [
        _collect(prying, key, pried)
        for key in (keys.study_results("bob.x"), keys.ALL_RESULTS, f"{keys.ROOT}/**")
    ]
    assert _answered(prying, [keys.STATUS])  # the router has taken the declarations above
    own: list[str] = []
    _own = _collect(alice, keys.study_results("alice.x"), own)
    probe = keys.result("alice.x", "probe")
    wait_for(lambda: router.session.put(probe, b"") or probe in own, what="alice's subscription")
    for key in (keys.result("bob.x", "j1"), keys.result("alice.x", "j1")):
        router.session.put(key, b"")
    wait_for(lambda: keys.result("alice.x", "j1") in own, what="alice's result")
    assert keys.result("bob.x", "j1") not in own
    assert pried == []

    # Alice holds her studies' tokens, not bob's nor a worker's, and forges no result.
    _denied = [
        alice.liveliness().declare_token(keys.alive_study("bob.x")),
        alice.liveliness().declare_token(keys.alive_worker("cobot-1")),
    ]
    alice.put(keys.result("alice.x", "forged"), b"")
    _token = alice.liveliness().declare_token(keys.alive_study("alice.x"))
    wait_for(lambda: keys.alive_study("alice.x") in router.tokens(), what="alice's study token")
    assert router.tokens() & {keys.alive_study("bob.x"), keys.alive_worker("cobot-1")} == set()
    assert keys.result("alice.x", "forged") not in router.results


def test_a_revoked_participant_connects_but_may_do_nothing(
    router: Router, connect: Callable[..., zenoh.Session], stolen: Path, credentials: Path
) -> None:
    assert not (credentials / "analytic.mallory.pem").exists()
    mallory = connect(stolen, "analytic", "mallory")  # the CA signed her certificate
    mallory.put(keys.result("mallory.x", "forged"), b"")  # before her subscriber: not local
    results: list[str] = []
    _subscriber = _collect(mallory, keys.study_results("mallory.x"), results)
    _token = mallory.liveliness().declare_token(keys.alive_study("mallory.x"))
    assert _answered(mallory, [keys.submit("mallory.x"), keys.STATUS]) == set()
    sent = keys.result("mallory.x", "j1")
    router.session.put(sent, b"")
    wait_for(lambda: sent in router.results, what="the router's own subscriber to get it")
    assert keys.alive_study("mallory.x") not in router.tokens()  # and half a second for `sent`
    assert results == []
    assert router.results == [sent], "her forged result never arrived"


def test_a_client_without_a_certificate_from_the_farms_ca_cannot_connect(
    router: Router, credentials: Path, tmp_path: Path
) -> None:
    write_dev_credentials(tmp_path, workers=("cobot-1",))  # another CA, same names
    with pytest.raises(ConnectionError):
        open_session(
            "client", connect=[router.endpoint], identity=TlsIdentity(tmp_path, "worker", "cobot-1")
        )
    # The farm's CA, so the client trusts the router, but no certificate of its own to show.
    identity = TlsIdentity(credentials, "worker", "cobot-1")
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(_tls_client(router.endpoint, identity, present_certificate=False))
    zenoh.open(_tls_client(router.endpoint, identity, present_certificate=True)).close()
    with pytest.raises(ConnectionError):
        open_session("client", connect=[router.endpoint.replace("tls/", "tcp/")])


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


def test_only_a_studys_owner_serves_its_models_and_any_worker_may_fetch_them(
    router: Router, connect: Callable[..., zenoh.Session], credentials: Path
) -> None:
    alice = connect(credentials, "analytic", "alice")
    bob = connect(credentials, "analytic", "bob")
    worker = connect(credentials, "worker", "cobot-1")
    own, bobs = keys.model("alice.x", "a" * 64), keys.model("alice.x", "b" * 64)
    _served = [
        alice.declare_queryable(own, lambda query: query.reply(query.key_expr, b"model")),
        bob.declare_queryable(bobs, lambda query: query.reply(query.key_expr, b"forged")),
        bob.declare_queryable(keys.ALL_MODELS, lambda query: query.reply(query.key_expr, b"x")),
    ]
    assert _answered(alice, [keys.STATUS]) and _answered(bob, [keys.STATUS])  # declared by now
    wait_for(lambda: _answered(worker, [own]), what="alice's model to be served")
    assert _answered(worker, [own, bobs]) == {own}
    replies = [reply.ok.payload.to_bytes() for reply in worker.get(own, timeout=1.0) if reply.ok]
    assert replies == [b"model"]  # bob's catch-all queryable was never declared
    # An analytic participant does not fetch models (another session of bob's: his own
    # queryables would answer his own query inside his session).
    assert _answered(connect(credentials, "analytic", "bob"), [own]) == set()


@pytest.mark.slow
def test_a_secure_farm_runs_jobs_end_to_end(credentials: Path, tmp_path: Path) -> None:
    """A real broker and a worker process, each with its own identity, and alice's client."""
    endpoint, tls = f"tls/127.0.0.1:{free_port()}", str(credentials)
    identity = TlsIdentity(credentials, "broker")
    with Broker([endpoint], lease_seconds=30.0, identity=identity) as broker:
        command = [
            sys.executable,
            "-m",
            "gainfarm.worker",
            "start",
            "--connect",
            endpoint,
            "--tls",
            tls,
        ]
        # cobot-2 by name (the directory holds two worker identities): the identity's name is
        # the worker's name.
        worker = subprocess.Popen(
            [*command, "--name", "cobot-2", "--log-level", "warning"],
            env={**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")},
        )
        # Job c adds a feed-forward model, which the worker fetches from alice's process.
        model = to_bytes(rigid_prior(IDEAL_PLANT.model_copy(update={"joints": "rigid"})))
        with_model = short_spec(duration=0.3).model_copy(update={"feedforward": digest(model)})
        try:
            alice = TlsIdentity(credentials, "analytic", "alice")
            with FarmClient(
                [endpoint], "alice.secure", tmp_path, identity=alice, models={digest(model): model}
            ) as farm:
                farm.submit({"a": short_spec(), "b": short_spec(duration=0.3), "c": with_model})
                evaluations = list(farm.results(timeout=60))
            wait_for(lambda: broker.queue.jobs_done == 3, what="the broker to count the jobs")
            status = [
                sys.executable,
                "-m",
                "gainfarm.broker",
                "status",
                "--json",
                "--connect",
                endpoint,
            ]
            for who in ("broker", "worker.cobot-1", "analytic.bob"):  # anyone may read it
                done = subprocess.run(
                    [*status, "--tls", tls, "--as", who], capture_output=True, text=True, timeout=60
                )
                assert done.returncode == 0, done.stderr
                assert json.loads(done.stdout)["jobs_done"] == 3
        finally:
            worker.terminate()
            assert worker.wait(15) == 0
    assert sorted(e.job_id for e in evaluations) == ["a", "b", "c"]
    assert all(e.status == JobStatus.ok and e.worker == "cobot-2" for e in evaluations)


@pytest.mark.slow
def test_a_worker_identity_cannot_forge_results_for_jobs_it_was_not_leased(
    credentials: Path, tmp_path: Path
) -> None:
    """Attempt 2: cobot-1, a real worker identity, knows alice's specs and study, hands in a
    perfect score for each job under its own name and puts it on the study's keys; cobot-2 runs
    the jobs. Only cobot-2's results count."""
    endpoint, tls = f"tls/127.0.0.1:{free_port()}", str(credentials)
    specs = {"a": short_spec(), "b": short_spec(duration=0.3)}
    with Broker([endpoint], lease_seconds=30.0, identity=TlsIdentity(credentials, "broker")):
        forger = open_session(
            "client", connect=[endpoint], identity=TlsIdentity(credentials, "worker", "cobot-1")
        )
        alice = TlsIdentity(credentials, "analytic", "alice")
        try:
            with FarmClient([endpoint], "alice.forged", tmp_path, identity=alice) as farm:
                farm.submit(specs)
                for job_id, spec in specs.items():
                    content = perfect_log(spec)
                    forged = result_for(
                        "alice.forged",
                        job_id,
                        worker="cobot-1",
                        lease_id="guessed",
                        episode_bytes=len(content),
                        digest=hashlib.sha256(content).hexdigest(),
                    )
                    verdict = hand_in(forger, forged)
                    assert not verdict.accepted and "not one of job" in verdict.reason
                    forger.put(  # as a worker sends a result: without its log
                        keys.result("alice.forged", job_id), b"", attachment=forged.to_bytes()
                    )
                wait_for(lambda: farm._inbox.qsize() >= 2, what="the forgeries to reach alice")
                command = [sys.executable, "-m", "gainfarm.worker", "start", "--connect", endpoint]
                worker = subprocess.Popen(
                    [*command, "--tls", tls, "--name", "cobot-2", "--log-level", "warning"]
                )
                try:
                    evaluations = list(farm.results(timeout=60))
                finally:
                    worker.terminate()
                    assert worker.wait(15) == 0
                assert farm.unconfirmed == 2
        finally:
            forger.close()
    assert sorted(e.job_id for e in evaluations) == ["a", "b"]
    assert all(e.worker == "cobot-2" and e.scores and e.scores.f_acc > 0 for e in evaluations)
