"""The secure farm: who each process is (a TLS identity) and what each participant may do (the
router's access policy).

Every process of a secure farm holds a certificate signed by the farm's CA. Its common name says
its role and its name: `broker` for the broker, `<role>.<name>` for a participant
(`worker.cobot-3`, `analytic.alice`). The router accepts TLS links only, from clients whose
certificate the CA signed (mutual authentication), and then lets each participant touch only the
keys of its own name: a worker asks for leases and hands in results under its own name, an
analytic participant submits to, reads the results of and holds only studies named
`<name>.<anything>`. Denied messages are dropped by Zenoh itself, before any gainfarm code sees
them. docs/security.md has the policy as a table, and how a site adds and revokes participants.

The router knows its participants from the certificates in its own credentials directory
(`<role>.<name>.pem`, no keys needed there), minus the names listed as revoked in it: the ACL
matches common names only, so a revoked certificate still connects (the CA signed it) but may do
nothing, and a revoked name is never issued again.
"""

import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast, get_args

from gainfarm.schemas import keys

Role = Literal["broker", "analytic", "worker"]
ROLES: tuple[Role, ...] = get_args(Role)
ParticipantRole = Literal["analytic", "worker"]
PARTICIPANT_ROLES: tuple[ParticipantRole, ...] = get_args(ParticipantRole)

CA_CERTIFICATE = "ca.pem"
BROKER = "broker"  # the broker's name and common name: there is one broker per farm
REVOKED = "revoked.txt"  # one common name a line: never allowed, never issued again
# No dots in a name: `alice.` then starts exactly alice's studies, and `<role>.<name>` splits one
# way only. The length keeps a study name (`<name>.<run>`) within the wire's 64 characters.
PARTICIPANT_PATTERN = r"[A-Za-z0-9_-]{1,32}"
PARTICIPANT_RULE = "1 to 32 letters, digits, '_' or '-'"
STUDY_SEPARATOR = "."


class UnknownIdentity(ValueError):
    """The identity asked for is not in the directory, or several are and none was named."""


@dataclass(frozen=True)
class TlsIdentity:
    """A participant's credentials, as `broker certs DIR` lays them out: DIR/ca.pem, then
    DIR/<common name>.pem and .key (DIR/broker.pem for the broker, DIR/worker.cobot-3.pem for
    worker cobot-3). A host needs only the CA certificate and its own pair."""

    directory: Path
    role: Role
    name: str = ""  # the participant's name; the broker's is always `broker`

    def __post_init__(self) -> None:
        if self.role == "broker":
            if self.name not in ("", BROKER):
                raise UnknownIdentity(
                    f"the broker's identity is named {BROKER!r}, not {self.name!r}"
                )
            object.__setattr__(self, "name", BROKER)
        elif not is_participant_name(self.name):
            raise UnknownIdentity(f"{self.name!r} is not a participant name: {PARTICIPANT_RULE}")

    @property
    def common_name(self) -> str:
        """What the certificate says and the access policy matches."""
        return BROKER if self.role == "broker" else f"{self.role}.{self.name}"

    @property
    def ca(self) -> Path:
        return self.directory / CA_CERTIFICATE

    @property
    def certificate(self) -> Path:
        return self.directory / f"{self.common_name}.pem"

    @property
    def private_key(self) -> Path:
        return self.directory / f"{self.common_name}.key"

    def check(self) -> None:
        """ValueError, in one line, naming the first credential file that is missing."""
        for path in (self.ca, self.certificate, self.private_key):
            if not path.is_file():
                raise ValueError(f"no {path} (make development credentials with `broker certs`)")

    def zenoh_tls(self, listening: bool) -> dict[str, Any]:
        """The `transport/link/tls` section: present our certificate, demand the peer's."""
        side = "listen" if listening else "connect"
        return {
            "root_ca_certificate": str(self.ca),
            f"{side}_certificate": str(self.certificate),
            f"{side}_private_key": str(self.private_key),
            "enable_mtls": True,
        }


def is_participant_name(name: str) -> bool:
    return re.fullmatch(PARTICIPANT_PATTERN, name) is not None


def owned_study(owner: str, study: str) -> str:
    """The name of `owner`'s study `study` on a secure farm: only `owner` may use it."""
    return f"{owner}{STUDY_SEPARATOR}{study}"


def parse_common_name(common_name: str) -> tuple[Role, str] | None:
    """(role, name) of a common name this farm issues, or None for anything else."""
    if common_name == BROKER:
        return "broker", BROKER
    role, _, name = common_name.partition(".")
    if role in PARTICIPANT_ROLES and is_participant_name(name):
        return cast(ParticipantRole, role), name
    return None


def revoked(directory: Path) -> set[str]:
    """The common names revoked in `directory` (its revoked.txt; '#' starts a comment)."""
    path = directory / REVOKED
    if not path.is_file():
        return set()
    lines = (line.split("#", 1)[0].strip() for line in path.read_text().splitlines())
    return {line for line in lines if line}


def identities(directory: Path, role: Role) -> list[TlsIdentity]:
    """The identities of `role` whose certificate is in `directory` and not revoked, by name."""
    if role == "broker":
        identity = TlsIdentity(directory, "broker")
        return [identity] if identity.certificate.is_file() else []
    gone = revoked(directory)
    found = []
    for path in sorted(directory.glob(f"{role}.*.pem")):
        parsed = parse_common_name(path.stem)
        if parsed is not None and parsed[0] == role and path.stem not in gone:
            found.append(TlsIdentity(directory, role, parsed[1]))
    return found


def participants(directory: Path) -> list[TlsIdentity]:
    """Everyone the router's policy lets in, the broker aside: every analytic and worker
    certificate in `directory` whose name is not revoked."""
    return [identity for role in PARTICIPANT_ROLES for identity in identities(directory, role)]


def load_identity(
    directory: Path | None, role: Role, name: str | None = None
) -> TlsIdentity | None:
    """The identity a `--tls DIR` option names (None without one): `name`'s, or without a name
    the only one of `role` in DIR. UnknownIdentity, in one line listing what DIR holds, when the
    name is not there or there are several and none was named; ValueError, in one line, when a
    credential file is missing or DIR holds no identity of `role`."""
    if directory is None:
        return None
    if role == "broker" or name is not None:
        identity = TlsIdentity(directory, role, name or "")
        missing = not identity.certificate.is_file() and identity.ca.is_file()
        if missing and role != "broker":
            raise UnknownIdentity(
                f"no {role} {identity.name!r} in {directory}/; {_holding(directory, role)}"
            )
        identity.check()
        return identity
    found = identities(directory, role)
    if len(found) > 1:
        raise UnknownIdentity(
            f"several {role} identities in {directory}/; {_holding(directory, role)}"
        )
    if not found:
        ca = directory / CA_CERTIFICATE
        if not ca.is_file():  # not a credentials directory at all
            raise ValueError(f"no {ca} (make development credentials with `broker certs`)")
        raise ValueError(f"no {role} identity in {directory}/; {_holding(directory, role)}")
    found[0].check()
    return found[0]


def _holding(directory: Path, role: Role) -> str:
    names = [identity.name for identity in identities(directory, role)]
    if not names:
        return f"it holds none (add one with `broker certs {directory} --{role} NAME`)"
    return f"it holds {', '.join(names)}"


# --- the router's access policy -------------------------------------------------------------


def _rule(rule_id: str, messages: list[str], flow: str, key_exprs: list[str]) -> dict[str, Any]:
    # Flows are seen from the router: ingress comes from the client, egress goes to it.
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": [flow],
        "messages": messages,
        "key_exprs": key_exprs,
    }


# `$*` matches within one chunk: `alice.$*` is every study alice owns and nobody else's (tested
# in tests/broker/test_security.py: a subscriber on `.../alice.x/...` or `.../alice.$*/...` is
# let in, one on `.../bob.x/...` or `.../*/...` is not).
def _owned(owner: str) -> str:
    return owned_study(owner, "$*")


def _analytic_rules(name: str) -> list[dict[str, Any]]:
    """Submit to, confirm, read the results of and hold only studies `name` owns."""
    who, studies = f"analytic.{name}", _owned(name)
    services = [keys.submit(studies), keys.confirm(studies), keys.STATUS]
    return [
        _rule(f"{who} asks", ["query"], "ingress", services),
        _rule(f"{who} is answered", ["reply"], "egress", services),
        _rule(
            f"{who} subscribes", ["declare_subscriber"], "ingress", [keys.study_results(studies)]
        ),
        _rule(f"{who} receives", ["put"], "egress", [keys.study_results(studies)]),
        # It serves its studies' feed-forward models to the workers that ask for them.
        _rule(
            f"{who} serves models",
            ["declare_queryable", "reply"],
            "ingress",
            [keys.model(studies, "*")],
        ),
        _rule(f"{who} is asked for models", ["query"], "egress", [keys.model(studies, "*")]),
        # It fetches its studies' episode logs from the workers that keep them.
        _rule(f"{who} fetches logs", ["query"], "ingress", [keys.log(studies, "*", "*")]),
        _rule(f"{who} receives logs", ["reply"], "egress", [keys.log(studies, "*", "*")]),
        _rule(
            f"{who} holds its studies",
            ["liveliness_token", "liveliness_query"],
            "ingress",
            [keys.alive_study(studies)],
        ),
        _rule(
            f"{who} watches the broker",
            ["declare_liveliness_subscriber"],
            "ingress",
            [keys.ALIVE_BROKER],
        ),
        _see_tokens(who),
    ]


def _worker_rules(name: str) -> list[dict[str, Any]]:
    """Lease and hand in results under its own name only. It may put a result in any study:
    a study counts a result only once the broker confirms that worker held that job's lease."""
    who = f"worker.{name}"
    services = [keys.lease(name), keys.STATUS]
    return [
        _rule(f"{who} asks", ["query"], "ingress", services),
        _rule(f"{who} is answered", ["reply"], "egress", services),
        _rule(f"{who} returns results", ["put"], "ingress", [keys.ALL_RESULTS]),
        # A job names its feed-forward model by content hash, so any study's may be fetched: a
        # model that does not hash to the job's digest is refused (worker/feedforward.py).
        _rule(f"{who} fetches models", ["query"], "ingress", [keys.ALL_MODELS]),
        _rule(f"{who} receives models", ["reply"], "egress", [keys.ALL_MODELS]),
        # It serves the logs it keeps under its own name only; an analytic process checks each
        # log against the digest the broker took, so a log served is trusted by its hash.
        _rule(
            f"{who} serves its logs",
            ["declare_queryable", "reply"],
            "ingress",
            [keys.worker_logs(name)],
        ),
        _rule(f"{who} is asked for its logs", ["query"], "egress", [keys.worker_logs(name)]),
        _rule(
            f"{who} holds its name",
            ["liveliness_token", "liveliness_query"],
            "ingress",
            [keys.alive_worker(name)],
        ),
        _see_tokens(who),
    ]


def _broker_rules() -> list[dict[str, Any]]:
    """`broker status` with the broker's own identity; the broker's services themselves run on
    the router's own session, which its access control does not filter."""
    return [
        _rule("broker asks", ["query"], "ingress", [keys.STATUS]),
        _rule("broker is answered", ["reply"], "egress", [keys.STATUS]),
    ]


def _see_tokens(who: str) -> dict[str, Any]:
    # Liveliness is how the farm notices a process gone; every participant sees every token
    # (worker and study names are not secret on a farm, only what may be done with them).
    return _rule(
        f"{who} sees tokens", ["liveliness_token", "reply"], "egress", [f"{keys.ROOT}/alive/**"]
    )


def participant_rules(identity: TlsIdentity) -> list[dict[str, Any]]:
    """What one identity may do, as access-control rules; anything else it is denied."""
    if identity.role == "analytic":
        return _analytic_rules(identity.name)
    if identity.role == "worker":
        return _worker_rules(identity.name)
    return _broker_rules()


def access_control(allowed: Iterable[TlsIdentity]) -> dict[str, Any]:
    """The router's `access_control` section: the broker's identity and each of `allowed`, by
    certificate common name, get their own rules; any other message from anyone is denied. A
    certificate the CA signed whose name is not allowed (revoked, or never given to this router)
    still connects, and may do nothing."""
    everyone = {identity.common_name: identity for identity in allowed}
    everyone[BROKER] = TlsIdentity(Path(), "broker")
    rules, subjects, policies = [], [], []
    for common_name, identity in sorted(everyone.items()):
        own = participant_rules(identity)
        rules += own
        subjects.append({"id": common_name, "cert_common_names": [common_name]})
        policies.append(
            {
                "id": f"{common_name} may",
                "rules": [rule["id"] for rule in own],
                "subjects": [common_name],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
