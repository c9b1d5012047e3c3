"""`broker start` and `broker status` as a user runs them: real processes, real Zenoh."""

import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from gainfarm.analytic.evaluators.local import free_port, spawn_worker, stop_workers
from gainfarm.schemas.wire import PROTOCOL_VERSION
from tests.helpers import wait_for


def broker_command(*arguments: str) -> list[str]:
    return [sys.executable, "-m", "gainfarm.broker", *arguments]


def status(endpoint: str, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        broker_command("status", "--connect", endpoint, *extra),
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "160"},
    )


@pytest.mark.slow
def test_a_started_broker_serves_workers_reports_them_and_stops_on_sigterm() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    broker = subprocess.Popen(
        broker_command("start", "--listen", endpoint),
        stderr=subprocess.PIPE,
        text=True,
    )
    worker = spawn_worker(endpoint, "cobot-7")
    try:
        give_up = time.monotonic() + 30
        while True:
            run = status(endpoint, "--json")
            if run.returncode == 0 and json.loads(run.stdout)["workers"]:
                break
            assert time.monotonic() < give_up, run.stderr
            time.sleep(0.2)
        farm = json.loads(run.stdout)
        assert farm["protocol"] == PROTOCOL_VERSION
        assert farm["workers"] == [{"name": "cobot-7", "busy": False, "job": "", "jobs_done": 0}]
        table = status(endpoint)
        assert table.returncode == 0
        assert "1 worker (0 busy)" in table.stdout and "cobot-7" in table.stdout
        assert "0 studies" in table.stdout and "0 jobs done" in table.stdout
    finally:
        stop_workers([worker])
        broker.send_signal(signal.SIGTERM)
        _, log = broker.communicate(timeout=30)
    assert broker.returncode == 0
    assert "broker listening on " + endpoint in log
    assert "worker cobot-7 joined" in log


def accepting(port: int) -> bool:
    """Whether something accepts TCP connections on 127.0.0.1:`port`."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0):
            return True
    except OSError:
        return False


def test_a_broker_that_cannot_listen_says_so_in_one_line() -> None:
    taken = free_port()
    with subprocess.Popen(broker_command("start", "--listen", f"tcp/127.0.0.1:{taken}")) as first:
        # The port is taken once the first broker listens, not after a guessed sleep: on a
        # loaded machine the second one had bound it first and served on (CI, 2026-11-26).
        wait_for(lambda: accepting(taken), 60, "the first broker to listen")
        run = subprocess.run(
            broker_command("start", "--listen", f"tcp/127.0.0.1:{taken}"),
            capture_output=True,
            text=True,
            timeout=60,
        )
        first.terminate()
    assert run.returncode == 2
    assert run.stderr.startswith("broker: error: --listen: cannot open a Zenoh router session")
    assert len(run.stderr.splitlines()) == 1


def test_a_bad_endpoint_is_one_line() -> None:
    run = subprocess.run(
        broker_command("start", "--listen", "nonsense"), capture_output=True, text=True, timeout=60
    )
    assert run.returncode == 2
    assert run.stderr.startswith("broker: error: --listen: bad endpoint: Endpoints must be")
    assert len(run.stderr.splitlines()) == 1


@pytest.mark.slow
def test_status_watch_prints_a_line_a_look_until_ctrl_c() -> None:
    """Off a terminal, --watch prints the farm's summary (or its JSON) at each look; Ctrl-C
    ends it with exit status 130 and one line, as every command line."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    broker = subprocess.Popen(broker_command("start", "--listen", endpoint, "--log-level", "error"))
    try:
        wait_for(lambda: status(endpoint).returncode == 0, 30, "the broker")
        for extra, parse in ((), str), (("--json",), json.loads):
            watching = subprocess.Popen(
                broker_command(
                    "status", "--connect", endpoint, "--watch", "--interval", "0.2", *extra
                ),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            assert watching.stdout is not None
            looks = [watching.stdout.readline() for _ in range(4)]
            watching.send_signal(signal.SIGINT)
            _, err = watching.communicate(timeout=30)
            assert watching.returncode == 130, err
            assert err == "broker: interrupted\n"
            if extra:
                uptimes = [parse(look)["uptime_s"] for look in looks]
                assert uptimes == sorted(uptimes) and uptimes[-1] > uptimes[0]
            else:
                assert all(
                    look.startswith("up ") and "0 workers (0 busy)" in look for look in looks
                )
    finally:
        broker.send_signal(signal.SIGTERM)
        broker.wait(timeout=30)


def test_certs_says_in_whole_sentences_what_each_host_needs(tmp_path) -> None:
    made = subprocess.run(
        broker_command("certs", str(tmp_path / "certs")), capture_output=True, text=True, timeout=60
    )
    assert made.returncode == 0, made.stderr
    assert made.stdout.endswith(
        "every host needs ca.pem and its own NAME.pem and NAME.key, and the broker's host also "
        "needs every participant's .pem\n"
    )


@pytest.mark.parametrize(
    ("arguments", "says"),
    [
        (["--host", ""], "--host: '' is neither a host name nor an IP address"),
        (["--host", "my broker"], "--host: 'my broker' is neither a host name nor an IP address"),
        (["--host", "-x.lan"], "--host: '-x.lan' is neither a host name nor an IP address"),
    ],
)
def test_certs_for_a_host_no_client_could_dial_is_one_line_and_writes_nothing(
    tmp_path, arguments: list[str], says: str
) -> None:
    refused = subprocess.run(
        broker_command("certs", str(tmp_path / "certs"), *arguments),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert refused.returncode == 2
    assert refused.stderr == f"broker: error: {says}\n"
    assert list(tmp_path.iterdir()) == []


def test_certs_under_a_file_names_the_directory_option(tmp_path) -> None:
    (tmp_path / "notes").write_text("mine")
    refused = subprocess.run(
        broker_command("certs", str(tmp_path / "notes" / "certs")),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert refused.returncode == 2
    assert refused.stderr == (
        f"broker: error: DIR: cannot write {str(tmp_path / 'notes' / 'certs')!r}: Not a directory\n"
    )


def test_certs_into_a_file_is_one_plain_line(tmp_path) -> None:
    file = tmp_path / "certs"
    file.write_text("not a directory")
    refused = subprocess.run(
        broker_command("certs", str(file)), capture_output=True, text=True, timeout=60
    )
    assert refused.returncode == 2
    assert refused.stderr == f"broker: error: DIR: {str(file)!r} is a file, not a directory\n"
    assert file.read_text() == "not a directory"
