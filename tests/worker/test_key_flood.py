"""Big queries on a worker's log keys (issue 47, item 4): a real flooder process asks with
payloads larger than any wire message while a real `worker start` process runs a real job. The
worker's session takes no message larger than SERVING_SESSION_BYTES, so Zenoh drops each big
query on the way: none is ever answered, while small queries on the same keys are, and the jobs
run during and after the flood make the log they make without one."""

from pathlib import Path

import zenoh

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session
from gainfarm.schemas import keys
from gainfarm.schemas.parts import selector
from gainfarm.worker.job import simulate
from tests.analytic.flooder import STUDY, Study, farm_processes, flooding_keys
from tests.helpers import short_spec

FLOOD_MIB = 8


def ask_worker(session: zenoh.Session, key: str) -> tuple[bool, bytes]:
    """(ok, payload) of the one answer to a small query on a worker's key."""
    (reply,) = session.get(key, timeout=10.0)
    if reply.ok is not None:
        return True, reply.ok.payload.to_bytes()
    return False, reply.err.payload.to_bytes()


def test_a_worker_drops_big_queries_on_its_log_keys_and_serves_on(tmp_path: Path) -> None:
    assert FLOOD_MIB * 2**20 > SERVING_SESSION_BYTES
    calm = simulate(short_spec())
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with (
        farm_processes(endpoint, ["w"], tmp_path / "broker.log"),
        open_session("client", connect=[endpoint]) as session,
    ):
        study = Study(session)
        # The log the job makes, and one no worker has: a big query that reached the worker
        # would be answered either way (with the log, or with a refusal).
        kept, missing = keys.log(STUDY, "w", calm.digest), keys.log(STUDY, "w", "0" * 64)
        with flooding_keys(endpoint, FLOOD_MIB, ask=[kept, missing]) as counts:
            during = study.run("during")
            # Small ones are answered (the log is one part).
            assert ask_worker(session, selector(kept, 0)) == (True, calm.content)
            gone = f"no such log: {missing} (never made, or no longer kept)"
            assert ask_worker(session, selector(missing, 0)) == (False, gone.encode())
        after = study.run("after")
    # Each big query went unanswered until the router gave up on it.
    assert counts.sent >= 2 and counts.answered == 0 and counts.timed_out >= 1, counts
    for result in (during, after):
        # The very log it makes without a flood (its scores are the log's: the digest says all).
        assert result.status == calm.status and result.digest == calm.digest
    print(f"{counts.sent} queries of {FLOOD_MIB} MiB sent, none answered")
