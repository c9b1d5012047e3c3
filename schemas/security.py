"""The secure farm: who each process is (a TLS identity) and what each identity may do (the
router's access policy).

Every process of a secure farm holds a certificate signed by the farm's CA; its common name is its
role. The router accepts TLS links only, from clients whose certificate the CA signed (mutual
authentication), and then lets each role touch only its own keys: analytic processes submit jobs
and read results, workers take leases and return results. Denied messages are dropped by Zenoh
itself, before any gainfarm code sees them.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from schemas import keys

Role = Literal["broker", "analytic", "worker"]
ROLES: tuple[Role, ...] = ("broker", "analytic", "worker")
CA_CERTIFICATE = "ca.pem"


@dataclass(frozen=True)
class TlsIdentity:
    """A role's credentials, as `broker certs DIR` lays them out: DIR/ca.pem, DIR/<role>.pem and
    DIR/<role>.key. A host needs only the CA certificate and its own role's pair."""

    directory: Path
    role: Role

    @property
    def ca(self) -> Path:
        return self.directory / CA_CERTIFICATE

    @property
    def certificate(self) -> Path:
        return self.directory / f"{self.role}.pem"

    @property
    def private_key(self) -> Path:
        return self.directory / f"{self.role}.key"

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


def _rule(rule_id: str, messages: list[str], flow: str, key_exprs: list[str]) -> dict[str, Any]:
    # Flows are seen from the router: ingress comes from the client, egress goes to it.
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": [flow],
        "messages": messages,
        "key_exprs": key_exprs,
    }


# What each role may do, and nothing else (the default is deny). Queries need their reply
# allowed on the way back; subscriptions need the data allowed out.
RULES = [
    _rule("submit jobs", ["query"], "ingress", [keys.SUBMIT]),
    _rule("ask for work", ["query"], "ingress", [keys.LEASE]),
    _rule("read status", ["query"], "ingress", [keys.STATUS]),
    _rule("get answers", ["reply"], "egress", [keys.SUBMIT, keys.LEASE, keys.STATUS]),
    _rule("return results", ["put"], "ingress", [keys.ALL_RESULTS]),
    _rule("subscribe to results", ["declare_subscriber"], "ingress", [keys.ALL_RESULTS]),
    _rule("receive results", ["put"], "egress", [keys.ALL_RESULTS]),
    _rule(
        "hold a study", ["liveliness_token", "liveliness_query"], "ingress", [keys.ALIVE_STUDIES]
    ),
    _rule(
        "hold a worker", ["liveliness_token", "liveliness_query"], "ingress", [keys.ALIVE_WORKERS]
    ),
    _rule("watch the broker", ["declare_liveliness_subscriber"], "ingress", [keys.ALIVE_BROKER]),
    _rule("see tokens", ["liveliness_token", "reply"], "egress", [f"{keys.ROOT}/alive/**"]),
]

POLICY: dict[Role, list[str]] = {
    "analytic": [
        "submit jobs",
        "read status",
        "get answers",
        "subscribe to results",
        "receive results",
        "hold a study",
        "watch the broker",
        "see tokens",
    ],
    "worker": [
        "ask for work",
        "read status",
        "get answers",
        "return results",
        "hold a worker",
        "see tokens",
    ],
    "broker": ["read status", "get answers"],  # `broker status` with the broker's own identity
}


def access_control() -> dict[str, Any]:
    """The router's `access_control` section: each role, by certificate common name, gets its
    rules; any other message from anyone is denied."""
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": RULES,
        "subjects": [{"id": role, "cert_common_names": [role]} for role in ROLES],
        "policies": [
            {"id": f"{role} may", "rules": rules, "subjects": [role]}
            for role, rules in POLICY.items()
        ],
    }


def load_identity(directory: Path | None, role: Role) -> TlsIdentity | None:
    """The identity a `--tls DIR` option names (None without one); ValueError, in one line,
    when a credential file is missing."""
    if directory is None:
        return None
    identity = TlsIdentity(directory, role)
    identity.check()
    return identity
