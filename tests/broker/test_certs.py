"""Development credentials: a CA and one certificate per role, each named after its role."""

import subprocess
import sys
from pathlib import Path

from cryptography import x509
from cryptography.x509.oid import NameOID

from broker.certs import write_dev_credentials
from schemas.security import ROLES, TlsIdentity


def _load(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def test_every_role_gets_a_certificate_named_after_it_and_signed_by_the_ca(tmp_path: Path) -> None:
    write_dev_credentials(tmp_path, ("broker", "10.0.0.1"))
    ca = _load(tmp_path / "ca.pem")
    for role in ROLES:
        identity = TlsIdentity(tmp_path, role)
        identity.check()
        certificate = _load(identity.certificate)
        certificate.verify_directly_issued_by(ca)  # raises if the CA did not sign it
        (common_name,) = certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
        assert common_name.value == role
        assert identity.private_key.stat().st_mode & 0o777 == 0o600  # keys are the owner's alone
    names = _load(TlsIdentity(tmp_path, "broker").certificate).extensions.get_extension_for_class(
        x509.SubjectAlternativeName
    )
    assert names.value.get_values_for_type(x509.DNSName) == ["broker"]
    assert [str(ip) for ip in names.value.get_values_for_type(x509.IPAddress)] == ["10.0.0.1"]


def test_existing_credentials_are_never_overwritten(tmp_path: Path) -> None:
    write_dev_credentials(tmp_path, ("localhost",))
    before = {path.name: path.read_bytes() for path in tmp_path.iterdir()}
    command = [sys.executable, "-m", "broker", "certs", str(tmp_path)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert done.returncode != 0
    assert done.stderr.count("\n") == 1 and "delete the old credentials" in done.stderr
    assert {path.name: path.read_bytes() for path in tmp_path.iterdir()} == before
    # --if-missing (compose runs it at every `up`) keeps a complete set, but not a partial one.
    done = subprocess.run([*command, "--if-missing"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "kept them" in done.stdout
    assert {path.name: path.read_bytes() for path in tmp_path.iterdir()} == before
    (tmp_path / "worker.pem").unlink()
    done = subprocess.run([*command, "--if-missing"], capture_output=True, text=True, timeout=60)
    assert done.returncode != 0 and not (tmp_path / "worker.pem").exists()


def test_a_missing_credential_is_named_in_one_line(tmp_path: Path) -> None:
    write_dev_credentials(tmp_path, ("localhost",))
    (tmp_path / "worker.key").unlink()
    command = [sys.executable, "-m", "worker", "start", "--connect", "tls/127.0.0.1:1"]
    done = subprocess.run(
        [*command, "--tls", str(tmp_path)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode != 0
    assert done.stderr.count("\n") == 1 and "worker.key" in done.stderr
