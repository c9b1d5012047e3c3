"""A flood of idle connections must not keep honest clients off the broker's port.

Each test opens a router on a free loopback port as the broker does (gainfarm/edges/transport.py),
opens FLOOD raw TCP connections to it that never say a word, and, while they are all still open,
times an honest client from its first attempt to its first answered query. With Zenoh's defaults the
plain router turns every newcomer away for 10 s (100 idle connections fill its pending handshakes
and it closes the rest at once), and the TLS router, once the idle handshakes time out after 10 s,
pauses 100 ms for each of them and admits nobody for 30 s. `pytest -s` prints the figures.
"""

import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.certs import write_dev_credentials
from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.security import TlsIdentity

FLOOD = 300  # idle connections, as in the attack
JOIN_SECONDS = 3.0  # an honest client is in and answered within this, flood or no flood
# Zenoh's default TLS handshake timeout: a flood held longer than this is what locked TLS
# clients out, so the TLS test joins only after it has passed.
DEFAULT_TLS_HANDSHAKE_SECONDS = 10.0


@pytest.fixture(scope="module")
def credentials(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("credentials")
    write_dev_credentials(directory, workers=("cobot-1",))
    return directory


@contextmanager
def _router(endpoint: str, identity: TlsIdentity | None) -> Iterator[zenoh.Session]:
    """A router as the broker opens it, answering status queries."""
    router = open_session("router", listen=[endpoint], identity=identity)
    try:
        _status = router.declare_queryable(keys.STATUS, lambda query: query.reply(keys.STATUS, b""))
        yield router
    finally:
        router.close()


@contextmanager
def _flood(port: int, count: int = FLOOD) -> Iterator[list[socket.socket]]:
    """`count` TCP connections that say nothing, open until the block ends."""
    connections: list[socket.socket] = []
    try:
        for _ in range(count):
            connections.append(socket.create_connection(("127.0.0.1", port), timeout=5.0))
        yield connections
    finally:
        for connection in connections:
            connection.close()


def _join(endpoint: str, identity: TlsIdentity | None) -> tuple[float, int]:
    """(seconds, attempts) an honest client takes to open a session and get a status answer,
    trying again at once after each refusal, as a worker does; fails after JOIN_SECONDS."""
    start = time.monotonic()
    attempts = 0
    while True:
        attempts += 1
        try:
            client = open_session("client", connect=[endpoint], identity=identity)
        except ConnectionError:
            if time.monotonic() - start > JOIN_SECONDS:
                raise AssertionError(
                    f"no client could join within {JOIN_SECONDS} s ({attempts} attempts)"
                ) from None
            continue
        try:
            replies = client.get(keys.STATUS, timeout=JOIN_SECONDS)
            assert [reply.ok is not None for reply in replies] == [True], "no status answer"
        finally:
            client.close()
        return time.monotonic() - start, attempts


def test_a_client_joins_a_plain_router_while_idle_connections_crowd_it() -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with _router(endpoint, None), _flood(port):
        time.sleep(0.5)  # the router has taken every idle connection in, ahead of the client
        seconds, attempts = _join(endpoint, None)
    print(f"plain: joined in {seconds:.3f} s ({attempts} attempts) with {FLOOD} idle connections")
    assert seconds < JOIN_SECONDS


@pytest.mark.slow
def test_a_client_joins_a_tls_router_while_idle_connections_outlast_the_handshake(
    credentials: Path,
) -> None:
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    worker = TlsIdentity(credentials, "worker", "cobot-1")
    with _router(endpoint, TlsIdentity(credentials, "broker")), _flood(port):
        time.sleep(DEFAULT_TLS_HANDSHAKE_SECONDS + 0.5)
        seconds, attempts = _join(endpoint, worker)
    print(f"tls: joined in {seconds:.3f} s ({attempts} attempts) with {FLOOD} idle connections")
    assert seconds < JOIN_SECONDS
