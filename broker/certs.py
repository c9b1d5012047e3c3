"""Development credentials for a secure farm: a CA, and a certificate per participant signed by it.

`broker certs DIR` writes DIR/ca.pem and DIR/ca.key, DIR/broker.pem and DIR/broker.key, then for
each participant DIR/<role>.<name>.pem and .key (`worker.cobot-3.pem`). Each certificate's common
name is its file's stem: that is what the router's access policy (schemas/security.py) matches.
The broker's certificate names the hosts clients dial (`--host`), since clients check it against
the endpoint they connect to.

Run again on a directory that holds the CA, it adds the participants named, signed by that CA; it
never replaces a CA, nor a certificate already there. `revoke` removes a participant's pair and
records its common name in DIR/revoked.txt: the router denies it everything after its next start,
and the name is never issued again (the ACL tells certificates apart by common name only, so a new
certificate under a revoked name would let the old one back in).

For production, issue the same layout from your own CA; keep ca.key off the farm's hosts.
"""

import datetime
import ipaddress
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from gainfarm.edges.files import write_atomically
from gainfarm.schemas.security import (
    BROKER,
    CA_CERTIFICATE,
    PARTICIPANT_ROLES,
    REVOKED,
    ParticipantRole,
    TlsIdentity,
    parse_common_name,
    revoked,
)

DEFAULT_HOSTS = ("localhost", "127.0.0.1")
# What `broker certs DIR` issues with a new CA when no participant is named: a working
# development farm of one analytic participant and one worker.
DEFAULT_ANALYTICS = ("dev",)
DEFAULT_WORKERS = ("cobot-1",)
CA_KEY = "ca.key"
CA_NAME = "gainfarm development CA"

PrivateKey = ec.EllipticCurvePrivateKey


@dataclass
class Issued:
    """What one run did: the files it wrote, and the identities it found already there."""

    written: list[Path] = field(default_factory=list)
    kept: list[TlsIdentity] = field(default_factory=list)


def write_dev_credentials(
    directory: Path,
    hosts: Sequence[str] = DEFAULT_HOSTS,
    days: int = 365,
    if_missing: bool = False,
    analytics: Sequence[str] = (),
    workers: Sequence[str] = (),
) -> Issued:
    """Make sure `directory` holds a CA, the broker's pair and the participants named, issuing
    what is missing from the CA there (a new one if there is none); with no participant named and
    a new CA, DEFAULT_ANALYTICS and DEFAULT_WORKERS. The broker's pair, once there, is kept.

    FileExistsError if a participant named already has a certificate (with `if_missing`, it is
    kept), or if nothing is named and nothing is missing (with `if_missing`, nothing is written).
    ValueError, in one line, for a name that is not a participant name or was revoked, for a
    directory with certificates but no CA (a new CA would lock them out), or when the CA's key is
    needed and absent."""
    requested = _requested(directory, analytics, workers)
    ca_pem, ca_key = directory / CA_CERTIFICATE, directory / CA_KEY
    new_ca = not ca_pem.exists() and not ca_key.exists()
    if new_ca:
        strays = _certificates(directory)
        if strays:
            raise ValueError(
                f"{strays[0]} exists but {ca_pem} does not: a new CA would not have signed it; "
                "restore the CA or delete the old credentials"
            )
        requested = requested or _requested(directory, DEFAULT_ANALYTICS, DEFAULT_WORKERS)
    gone = revoked(directory)
    issued = Issued()
    to_issue = []
    broker = TlsIdentity(directory, "broker")
    if broker.certificate.exists():
        issued.kept.append(broker)  # every later run reuses it (delete it to change --host)
    elif new_ca or ca_key.exists():
        to_issue.append(broker)
    for identity in requested:
        if identity.common_name in gone:
            raise ValueError(
                f"{identity.common_name} was revoked in {directory / REVOKED}: "
                "a revoked name is never issued again, pick another"
            )
        # A certificate without its key is a participant whose key went to its own host (the
        # broker's directory holds every participant's certificate, no participant's key).
        if not identity.certificate.exists():
            to_issue.append(identity)
        elif if_missing:
            issued.kept.append(identity)
        else:
            raise FileExistsError(
                f"{identity.certificate} exists; revoke {identity.common_name} "
                "and issue a new name to replace it"
            )
    if not requested and not to_issue and not if_missing:
        raise FileExistsError(
            f"{directory}/ already holds a CA: name the participants to add "
            "(--analytic NAME, --worker NAME), or delete the old credentials to start again"
        )
    if not to_issue:
        return issued
    directory.mkdir(parents=True, exist_ok=True)
    if new_ca:
        key, ca = _authority(days)
        _write_pair(ca_pem, ca_key, ca, key)
        issued.written += [ca_pem, ca_key]
    else:
        key, ca = _load_authority(ca_pem, ca_key)
    for identity in to_issue:
        names = tuple(hosts) if identity.role == "broker" else ()
        subject_key, certificate = _issue(key, ca, identity.common_name, names, days)
        _write_pair(identity.certificate, identity.private_key, certificate, subject_key)
        issued.written += [identity.certificate, identity.private_key]
    return issued


def revoke(directory: Path, who: str) -> TlsIdentity:
    """Revoke `who` (a common name such as `worker.cobot-3`, or a bare name that only one
    participant in `directory` has): record it in DIR/revoked.txt, then delete its pair there.

    ValueError, in one line, for the broker, an unknown bare name or an ambiguous one. A common
    name is recorded even with no certificate here, so that it is never issued again."""
    if who == BROKER:
        raise ValueError(
            "the broker's identity cannot be revoked: make a new CA and credentials for everyone"
        )
    parsed = parse_common_name(who)
    if parsed is not None:
        role, name = parsed
        identity = TlsIdentity(directory, role, name)
    else:
        holders = [
            TlsIdentity(directory, role, who)
            for role in PARTICIPANT_ROLES
            if (directory / f"{role}.{who}.pem").exists()
        ]
        if len(holders) != 1:
            held = " and ".join(h.common_name for h in holders) or "no participant"
            raise ValueError(f"{who!r}: {held} in {directory}/ by that name; give role.name")
        identity = holders[0]
    gone = revoked(directory)
    if identity.common_name not in gone:
        path = directory / REVOKED
        before = path.read_text() if path.is_file() else _REVOKED_HEADER
        if before and not before.endswith("\n"):
            before += "\n"
        write_atomically(path, f"{before}{identity.common_name}\n".encode())
    identity.certificate.unlink(missing_ok=True)
    identity.private_key.unlink(missing_ok=True)
    return identity


_REVOKED_HEADER = (
    "# Revoked identities, one common name a line: the router denies them everything after its\n"
    "# next start, and `broker certs` never issues these names again.\n"
)


def _requested(
    directory: Path, analytics: Sequence[str], workers: Sequence[str]
) -> list[TlsIdentity]:
    roles: list[tuple[ParticipantRole, Sequence[str]]] = [
        ("analytic", analytics),
        ("worker", workers),
    ]
    # TlsIdentity checks each name (UnknownIdentity, a ValueError, in one line); once each.
    wanted = {TlsIdentity(directory, role, name) for role, names in roles for name in names}
    return sorted(wanted, key=lambda identity: identity.common_name)


def _certificates(directory: Path) -> list[Path]:
    """Certificates this layout would name, whatever signed them."""
    if not directory.is_dir():
        return []
    return sorted(
        path
        for path in directory.glob("*.pem")
        if path.name != CA_CERTIFICATE and parse_common_name(path.stem) is not None
    )


def _load_authority(ca_pem: Path, ca_key: Path) -> tuple[PrivateKey, x509.Certificate]:
    if not ca_key.is_file():
        raise ValueError(f"no {ca_key}: issue certificates where the CA's key is kept")
    if not ca_pem.is_file():
        raise ValueError(f"no {ca_pem} beside {ca_key}: restore it, a new CA would replace it")
    key = serialization.load_pem_private_key(ca_key.read_bytes(), password=None)
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        raise ValueError(f"{ca_key} is not an EC key as `broker certs` makes them")
    return key, x509.load_pem_x509_certificate(ca_pem.read_bytes())


def _authority(days: int) -> tuple[PrivateKey, x509.Certificate]:
    key = ec.generate_private_key(ec.SECP256R1())
    name = _name(CA_NAME)
    builder = (
        _builder(name, name, key, days)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_key_usage(signs_certificates=True), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
    )
    return key, builder.sign(key, hashes.SHA256())


def _issue(
    ca_key: PrivateKey,
    ca: x509.Certificate,
    common_name: str,
    hosts: tuple[str, ...],
    days: int,
) -> tuple[PrivateKey, x509.Certificate]:
    key = ec.generate_private_key(ec.SECP256R1())
    # Every identity may both accept and open TLS links: the broker's also serves `broker
    # status`. Only the broker's names hosts: clients check it against the endpoint they dial.
    usages = [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
    builder = (
        _builder(_name(common_name), ca.subject, key, days)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_key_usage(signs_certificates=False), critical=True)
        .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
    )
    if hosts:
        names = x509.SubjectAlternativeName([_host(host) for host in hosts])
        builder = builder.add_extension(names, critical=False)
    return key, builder.sign(ca_key, hashes.SHA256())


def _builder(
    subject: x509.Name, issuer: x509.Name, key: PrivateKey, days: int
) -> x509.CertificateBuilder:
    now = datetime.datetime.now(datetime.UTC)
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))  # tolerate clocks a little behind
        .not_valid_after(now + datetime.timedelta(days=days))
    )


def _key_usage(signs_certificates: bool) -> x509.KeyUsage:
    return x509.KeyUsage(
        digital_signature=not signs_certificates,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=signs_certificates,
        crl_sign=signs_certificates,
        encipher_only=False,
        decipher_only=False,
    )


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _host(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def _write_pair(
    certificate_path: Path, key_path: Path, certificate: x509.Certificate, key: PrivateKey
) -> None:
    # The key first: a certificate without its key is what a crash must not leave, since the
    # next run would keep the certificate and never write the key.
    pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    write_atomically(key_path, pem, mode=0o600)
    write_atomically(certificate_path, certificate.public_bytes(serialization.Encoding.PEM))
