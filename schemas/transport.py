"""Zenoh sessions as the farm opens them: explicit endpoints, no multicast scouting.

Every process names where to listen or connect; discovery by multicast would let two farms on one
network find each other by accident. With a TLS identity the session is the secure profile
(schemas/security.py): TLS links only, both sides authenticated, and a router enforcing the access
policy.
"""

import json
import re
from collections.abc import Sequence
from typing import Literal

import zenoh

from schemas.security import TlsIdentity, access_control


def session_config(
    mode: Literal["router", "client", "peer"],
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    identity: TlsIdentity | None = None,
) -> zenoh.Config:
    """ValueError, in one line, for an endpoint Zenoh cannot parse or one that does not match
    whether the session is secure."""
    _check_protocols([*listen, *connect], secure=identity is not None)
    config = zenoh.Config()
    try:
        config.insert_json5("mode", json.dumps(mode))
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    except zenoh.ZError as error:
        raise ValueError(f"bad endpoint: {_plain(error)}") from None
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    # Zenoh would move large samples between processes of one host through shared memory, but
    # every sender maps a 16 MiB pool into each receiver and it stays mapped after the sender
    # exits: with workers coming and going, the broker and the clients grew by 16 MiB per worker
    # ever started (bench/soak.py). Loopback TCP is fast enough for episode logs.
    config.insert_json5("transport/shared_memory/enabled", "false")
    if identity is not None:
        identity.check()
        tls = identity.zenoh_tls(listening=mode == "router")
        config.insert_json5("transport/link/tls", json.dumps(tls))
        config.insert_json5("transport/link/protocols", json.dumps(["tls"]))
        if mode == "router":
            config.insert_json5("access_control", json.dumps(access_control()))
    return config


def _check_protocols(endpoints: Sequence[str], secure: bool) -> None:
    for endpoint in endpoints:
        if secure and not endpoint.startswith("tls/"):
            raise ValueError(f"{endpoint}: a secure session takes tls/ endpoints only")
        if not secure and endpoint.startswith("tls/"):
            raise ValueError(f"{endpoint}: a tls/ endpoint needs TLS credentials (--tls DIR)")


def open_session(
    mode: Literal["router", "client", "peer"],
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    identity: TlsIdentity | None = None,
) -> zenoh.Session:
    """Open a session; ConnectionError with the endpoints in its message if that fails."""
    config = session_config(mode, listen, connect, identity)
    try:
        return zenoh.open(config)
    except zenoh.ZError as error:
        where = ", ".join([*listen, *connect]) or "nowhere"
        reason = _plain(error)
        raise ConnectionError(f"cannot open a Zenoh {mode} session on {where}: {reason}") from None


def token_held(session: zenoh.Session, key: str, timeout: float = 1.0) -> bool:
    """Whether some session holds a liveliness token on `key` now: a worker's or a study's name
    already taken, a broker up. Waits at most `timeout` s for the answers."""
    return any(True for _ in session.liveliness().get(key, timeout=timeout))


def _plain(error: Exception) -> str:
    """Zenoh's message without the Rust source locations it appends."""
    text = re.sub(r"\s+at \S+\.rs:\d+\.?", "", str(error))
    return re.sub(r"^Json5Err\(Message \{ msg: \"(.*?)\".*$", r"\1", text).strip()
