"""Zenoh sessions as the farm opens them: explicit endpoints, no multicast scouting.

Every process names where to listen or connect; discovery by multicast would let two farms on one
network find each other by accident. With a TLS identity the session is the secure profile
(schemas/security.py): TLS links only, both sides authenticated, and a router enforcing the access
policy for the participants whose certificates are in its credentials directory.

A router also bounds what a connection that has not yet identified itself may cost (see
ACCEPT_TIMEOUT_MS and the constants with it): a crowd of idle TCP connections must not keep
honest clients out.
"""

import json
import re
import resource
from collections.abc import Sequence
from typing import Literal

import zenoh

from gainfarm.schemas.security import TlsIdentity, access_control, participants
from gainfarm.schemas.wire import MAX_MESSAGE_BYTES, PART_BYTES

# A connection is accepted in two steps, and Zenoh bounds each (the defaults, 100 pending for up
# to 10 s each, let 300 idle sockets lock everyone out for 10 s, tests/broker/test_flood.py):
# - Zenoh's own handshake (InitSyn to OpenAck, two round trips from an honest client that sends
#   at once): a connection that has not finished it within ACCEPT_TIMEOUT_MS is dropped. 3 s is
#   six 500 ms round trips, and makes an idle flood last 3 s instead of 10.
ACCEPT_TIMEOUT_MS = 3000
# - how many connections may be in that handshake at once; beyond, a new one is closed at once,
#   honest or not. Many, so that an idle flood must outnumber them within ACCEPT_TIMEOUT_MS to
#   lock anyone out, but no more than half the process's file descriptors: past its limit accept()
#   fails for everyone and Zenoh's listener pauses after each failure.
ACCEPT_PENDING_MAX = 4096
ACCEPT_PENDING_MIN = 100  # Zenoh's default
# - before that, on a tls/ endpoint, the TLS handshake. Zenoh's TLS listener pauses 100 ms after
#   every handshake that fails or times out (a fixed constant in zenoh-link-tls), and admits
#   nobody meanwhile: 300 idle sockets timing out together cost 30 s of lockout. Dropping them
#   sooner would only bring that forward, so a silent TLS connection is held for a minute instead
#   of Zenoh's 10 s: while it is held it costs a file descriptor, and honest clients still join.
#   An honest TLS handshake takes milliseconds; docs/security.md says what this cannot prevent.
TLS_HANDSHAKE_TIMEOUT_MS = 60_000

# The largest message any session of the farm takes in, the broker's router included: any wire
# message (MAX_MESSAGE_BYTES) and 64 KiB for the key, the headers and an attachment, since Zenoh
# counts the whole message. Zenoh drops a larger one after its first SERVING_SESSION_BYTES instead
# of reassembling it, so a 250 MiB put or query costs every process nothing (docs/security.md,
# "Junk on every key"). Big bytes (an episode log, a model) move only in parts of PART_BYTES
# (schemas.parts), each the answer to a query of its own, so no session needs to take more; the
# router most of all, since Zenoh reassembles every message it forwards (a per-link or per-key
# limit does not exist, and its low-pass filter acts after reassembly).
SERVING_SESSION_BYTES = MAX_MESSAGE_BYTES + 64 * 1024
assert PART_BYTES + 64 * 1024 <= SERVING_SESSION_BYTES  # a part and its headers fit


def session_config(
    mode: Literal["router", "client", "peer"],
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    identity: TlsIdentity | None = None,
    max_message_bytes: int | None = None,
) -> zenoh.Config:
    """ValueError, in one line, for an endpoint Zenoh cannot parse or one that does not match
    whether the session is secure. `max_message_bytes`: a message received larger than this is
    dropped while Zenoh reassembles it, before anything else sees it (Zenoh's default: 1 GiB)."""
    _check_protocols([*listen, *connect], secure=identity is not None)
    router = mode == "router"
    # Zenoh takes the TLS handshake timeout per endpoint only (after `#`), not in transport/link.
    listening = [_with_handshake_timeout(endpoint) if router else endpoint for endpoint in listen]
    config = zenoh.Config()
    try:
        config.insert_json5("mode", json.dumps(mode))
        config.insert_json5("listen/endpoints", json.dumps(listening))
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
        tls = identity.zenoh_tls(listening=router)
        config.insert_json5("transport/link/tls", json.dumps(tls))
        config.insert_json5("transport/link/protocols", json.dumps(["tls"]))
        if router:
            allowed = participants(identity.directory)
            config.insert_json5("access_control", json.dumps(access_control(allowed)))
    if max_message_bytes is not None:
        config.insert_json5("transport/link/rx/max_message_size", json.dumps(max_message_bytes))
    if router:
        # Bound what connections that never finish a handshake cost (see the constants).
        config.insert_json5("transport/unicast/accept_timeout", json.dumps(ACCEPT_TIMEOUT_MS))
        config.insert_json5("transport/unicast/accept_pending", json.dumps(accept_pending()))
    return config


def accept_pending() -> int:
    """ACCEPT_PENDING_MAX, or half the file descriptors this process may open if that is less."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return ACCEPT_PENDING_MAX
    return max(ACCEPT_PENDING_MIN, min(ACCEPT_PENDING_MAX, soft // 2))


def _with_handshake_timeout(endpoint: str) -> str:
    """A tls/ listening endpoint with TLS_HANDSHAKE_TIMEOUT_MS in its configuration."""
    if not endpoint.startswith("tls/") or "tls_handshake_timeout_ms" in endpoint:
        return endpoint  # a site's own setting in the endpoint wins
    separator = ";" if "#" in endpoint else "#"
    return f"{endpoint}{separator}tls_handshake_timeout_ms={TLS_HANDSHAKE_TIMEOUT_MS}"


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
    max_message_bytes: int | None = None,
) -> zenoh.Session:
    """Open a session; ConnectionError with the endpoints in its message if that fails."""
    config = session_config(mode, listen, connect, identity, max_message_bytes)
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
