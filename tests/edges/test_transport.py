"""Sessions as the farm opens them, checked without a network: endpoints that do not match the
profile are refused, and a router bounds what idle connections may cost."""

from pathlib import Path

import pytest

from gainfarm.edges.transport import (
    ACCEPT_TIMEOUT_MS,
    TLS_HANDSHAKE_TIMEOUT_MS,
    accept_pending,
    session_config,
)
from gainfarm.schemas.security import TlsIdentity


def test_secure_and_plain_endpoints_are_not_mixed(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="needs TLS credentials"):
        session_config("client", connect=["tls/127.0.0.1:7447"])
    with pytest.raises(ValueError, match="tls/ endpoints only"):
        session_config(
            "client",
            connect=["tcp/127.0.0.1:7447"],
            identity=TlsIdentity(tmp_path, "worker", "cobot-1"),
        )


def test_a_router_holds_idle_connections_briefly_and_many_at_once(tmp_path: Path) -> None:
    config = session_config("router", listen=["tcp/127.0.0.1:7447"])
    assert config.get_json("transport/unicast/accept_timeout") == str(ACCEPT_TIMEOUT_MS)
    assert int(config.get_json("transport/unicast/accept_pending")) == accept_pending() >= 100
    for name in ("ca.pem", "broker.pem", "broker.key"):
        (tmp_path / name).write_text("")  # the layout only: no handshake is made here
    secure = session_config(
        "router",
        listen=["tls/127.0.0.1:7447", "tls/[::1]:7447#tls_handshake_timeout_ms=5"],
        identity=TlsIdentity(tmp_path, "broker"),
    )
    assert secure.get_json("listen/endpoints") == (
        f'["tls/127.0.0.1:7447#tls_handshake_timeout_ms={TLS_HANDSHAKE_TIMEOUT_MS}",'
        '"tls/[::1]:7447#tls_handshake_timeout_ms=5"]'
    )
    # A client's endpoints are where it dials: left as given.
    client = session_config("client", connect=["tcp/127.0.0.1:7447"])
    assert client.get_json("transport/unicast/accept_pending") == "100"
