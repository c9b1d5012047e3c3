"""Development credentials for a secure farm: a CA, and one certificate per role signed by it.

`broker certs DIR` writes DIR/ca.pem and DIR/ca.key, then DIR/<role>.pem and DIR/<role>.key for
the broker, analytic and worker roles. Each certificate's common name is its role: that is what
the router's access policy (schemas/security.py) matches. The broker's certificate names the hosts
clients dial (`--host`), since clients check it against the endpoint they connect to.

For production, issue the same layout from your own CA; keep ca.key off the farm's hosts.
"""

import datetime
import ipaddress
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from schemas.files import write_atomically
from schemas.security import CA_CERTIFICATE, ROLES, Role, TlsIdentity

DEFAULT_HOSTS = ("localhost", "127.0.0.1")
CA_KEY = "ca.key"
CA_NAME = "gainfarm development CA"

PrivateKey = ec.EllipticCurvePrivateKey


def write_dev_credentials(
    directory: Path, hosts: tuple[str, ...], days: int = 365, if_missing: bool = False
) -> list[Path]:
    """Write a new CA and every role's credentials into `directory`; return the files written.

    FileExistsError if it already holds any of them: replacing a CA locks out every host that
    trusts the old one, so that takes deleting the files on purpose. With `if_missing`, a
    complete set is left as it is (nothing written); a partial one is still an error."""
    directory.mkdir(parents=True, exist_ok=True)
    identities = [TlsIdentity(directory, role) for role in ROLES]
    planned = [directory / CA_CERTIFICATE, directory / CA_KEY]
    planned += [path for i in identities for path in (i.certificate, i.private_key)]
    existing = [path for path in planned if path.exists()]
    if if_missing and existing == planned:
        return []
    if existing:
        raise FileExistsError(f"{existing[0]} exists; delete the old credentials to make new ones")
    ca_key, ca = _authority(days)
    _write_pair(directory / CA_CERTIFICATE, directory / CA_KEY, ca, ca_key)
    for identity in identities:
        key, certificate = _issue(ca_key, ca, identity.role, hosts, days)
        _write_pair(identity.certificate, identity.private_key, certificate, key)
    return planned


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
    ca_key: PrivateKey, ca: x509.Certificate, role: Role, hosts: tuple[str, ...], days: int
) -> tuple[PrivateKey, x509.Certificate]:
    key = ec.generate_private_key(ec.SECP256R1())
    # Every role may both accept and open TLS links: the broker's identity also serves
    # `broker status`, and a name in the certificate is harmless for a client.
    names = hosts if role == "broker" else (role,)
    usages = [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
    builder = (
        _builder(_name(role), ca.subject, key, days)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_key_usage(signs_certificates=False), critical=True)
        .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
        .add_extension(x509.SubjectAlternativeName([_host(h) for h in names]), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
    )
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
    write_atomically(certificate_path, certificate.public_bytes(serialization.Encoding.PEM))
    pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    write_atomically(key_path, pem, mode=0o600)
