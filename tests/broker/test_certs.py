"""Development credentials: a CA, the broker's certificate, and one per participant named
`<role>.<name>`; adding participants later, revoking them, and how a worker finds its own."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.certs import write_dev_credentials
from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.security import TlsIdentity, participants
from tests.helpers import wait_for


def _load(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def _common_name(path: Path) -> str:
    (common_name,) = _load(path).subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(common_name.value)


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=60)


def _contents(directory: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in directory.iterdir()}


def test_each_participant_gets_a_certificate_named_role_dot_name_signed_by_the_ca(
    tmp_path: Path,
) -> None:
    write_dev_credentials(tmp_path, ("broker", "10.0.0.1"))  # the defaults: a development set
    ca = _load(tmp_path / "ca.pem")
    expected = {
        TlsIdentity(tmp_path, "broker"): "broker",
        TlsIdentity(tmp_path, "analytic", "dev"): "analytic.dev",
        TlsIdentity(tmp_path, "worker", "cobot-1"): "worker.cobot-1",
    }
    for identity, common_name in expected.items():
        identity.check()
        _load(identity.certificate).verify_directly_issued_by(ca)  # raises if the CA did not
        assert _common_name(identity.certificate) == common_name
        assert identity.private_key.stat().st_mode & 0o777 == 0o600  # keys are the owner's alone
    names = _load(TlsIdentity(tmp_path, "broker").certificate).extensions.get_extension_for_class(
        x509.SubjectAlternativeName
    )
    assert names.value.get_values_for_type(x509.DNSName) == ["broker"]
    assert [str(ip) for ip in names.value.get_values_for_type(x509.IPAddress)] == ["10.0.0.1"]


def test_running_again_adds_participants_signed_by_the_same_ca(tmp_path: Path) -> None:
    write_dev_credentials(tmp_path, analytics=("alice",), workers=("cobot-1",))
    before = _contents(tmp_path)
    done = _run("broker", "certs", str(tmp_path), "--worker", "cobot-2", "--analytic", "bob")
    assert done.returncode == 0, done.stderr
    assert "analytic.bob, worker.cobot-2" in done.stdout
    after = _contents(tmp_path)
    assert {name: after[name] for name in before} == before, "nothing there was replaced"
    assert set(after) - set(before) == {
        "analytic.bob.pem",
        "analytic.bob.key",
        "worker.cobot-2.pem",
        "worker.cobot-2.key",
    }
    ca = _load(tmp_path / "ca.pem")
    for common_name in ("analytic.bob", "worker.cobot-2"):
        _load(tmp_path / f"{common_name}.pem").verify_directly_issued_by(ca)
    assert [p.common_name for p in participants(tmp_path)] == [
        "analytic.alice",
        "analytic.bob",
        "worker.cobot-1",
        "worker.cobot-2",
    ]


@pytest.mark.slow
def test_existing_credentials_are_never_overwritten(tmp_path: Path) -> None:
    write_dev_credentials(tmp_path, workers=("cobot-1",))
    before = _contents(tmp_path)
    for args, message in [
        ((), "already holds a CA"),  # nothing new named: the CA is not replaced
        (("--worker", "cobot-1"), "worker.cobot-1.pem exists"),
        (("--worker", "a.b"), "--worker: 'a.b' is not a participant name"),
    ]:
        done = _run("broker", "certs", str(tmp_path), *args)
        assert done.returncode != 0, args
        assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
        assert _contents(tmp_path) == before
    # --if-missing (compose runs it at every `up`) keeps what is there and adds what is not.
    done = _run("broker", "certs", str(tmp_path), "--if-missing", "--worker", "cobot-1")
    assert done.returncode == 0 and "kept them" in done.stdout
    assert _contents(tmp_path) == before
    # Certificates with no CA beside them: a new CA would not have signed them.
    (tmp_path / "ca.pem").unlink()
    (tmp_path / "ca.key").unlink()
    done = _run("broker", "certs", str(tmp_path), "--if-missing")
    assert done.returncode != 0 and "ca.pem does not" in done.stderr
    assert not (tmp_path / "ca.pem").exists()


@pytest.mark.slow
def test_a_revoked_identity_is_removed_and_its_name_never_issued_again(tmp_path: Path) -> None:
    write_dev_credentials(tmp_path, analytics=("alice",), workers=("cobot-1", "cobot-2"))
    done = _run("broker", "certs", str(tmp_path), "--revoke", "cobot-2")
    assert done.returncode == 0, done.stderr
    assert "revoked worker.cobot-2" in done.stdout and "restart the broker" in done.stdout
    assert not (tmp_path / "worker.cobot-2.pem").exists()
    assert not (tmp_path / "worker.cobot-2.key").exists()
    assert "worker.cobot-2" in (tmp_path / "revoked.txt").read_text()
    assert [p.common_name for p in participants(tmp_path)] == ["analytic.alice", "worker.cobot-1"]
    # Its certificate, copied back by mistake, still lets nobody in.
    write_dev_credentials(tmp_path / "elsewhere", workers=("cobot-2",))
    shutil.copy(tmp_path / "elsewhere" / "worker.cobot-2.pem", tmp_path)
    assert "worker.cobot-2" not in [p.common_name for p in participants(tmp_path)]
    for args, message in [
        (("--worker", "cobot-2"), "was revoked"),
        (("--revoke", "nobody"), "--revoke: 'nobody'"),
        (("--revoke", "broker"), "the broker's identity cannot be revoked"),
    ]:
        done = _run("broker", "certs", str(tmp_path), *args)
        assert done.returncode != 0, args
        assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr


def test_a_missing_credential_is_named_in_one_line(tmp_path: Path) -> None:
    write_dev_credentials(tmp_path, workers=("cobot-1",))
    (tmp_path / "worker.cobot-1.key").unlink()
    done = _run("worker", "start", "--connect", "tls/127.0.0.1:1", "--tls", str(tmp_path))
    assert done.returncode != 0
    assert done.stderr.count("\n") == 1 and "worker.cobot-1.key" in done.stderr


@pytest.mark.slow
def test_a_worker_on_a_secure_farm_is_named_after_its_identity(tmp_path: Path) -> None:
    write_dev_credentials(tmp_path, workers=("cobot-1", "cobot-2"))
    start = ["worker", "start", "--connect", "tls/127.0.0.1:1", "--tls", str(tmp_path)]
    for args, message in [
        ((), "--name: several worker identities"),  # which one?
        (("--name", "cobot-3"), "--name: no worker 'cobot-3'"),
    ]:
        done = _run(*start, *args)
        assert done.returncode != 0
        assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
        assert "cobot-1, cobot-2" in done.stderr  # what there is to choose from
    # A worker's host holds the CA's certificate and its own pair only: that is its name.
    host = tmp_path / "cobot-2-host"
    host.mkdir()
    for name in ("ca.pem", "worker.cobot-2.pem", "worker.cobot-2.key"):
        shutil.copy(tmp_path / name, host / name)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = open_session("router", listen=[endpoint], identity=TlsIdentity(tmp_path, "broker"))
    command = [
        sys.executable,
        "-m",
        "gainfarm.worker",
        "start",
        "--connect",
        endpoint,
        "--tls",
        str(host),
    ]
    worker = subprocess.Popen(command)
    try:
        token = keys.alive_worker("cobot-2")
        wait_for(
            lambda: any(True for _ in router.liveliness().get(token, timeout=0.5)),
            timeout=30,
            what="worker cobot-2's token",
        )
    finally:
        worker.terminate()
        worker.wait(15)
        router.close()
