"""Big queries on a worker's log keys (issue 47, item 4): a real flooder process asks with
payloads larger than any wire message while a real worker runs a real job. The worker's session
takes no message larger than SERVING_SESSION_BYTES, so Zenoh drops each big query on the way:
none is ever answered, while small queries on the same keys are, and the job's result is the one
it has without a flood."""

import threading

import zenoh

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.service import Broker
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session
from gainfarm.schemas import keys
from gainfarm.schemas.wire import Job, Result, Submission, SubmitReply, decode
from gainfarm.worker.job import simulate
from gainfarm.worker.service import CobotWorker
from tests.analytic.flooder import flooding_keys
from tests.helpers import open_study, query, short_spec, wait_for

FLOOD_MIB = 8
STUDY = "flooded"


def _submit(session: zenoh.Session, job_id: str) -> None:
    jobs = [Job(job_id=job_id, spec=short_spec(), keep_log=False)]
    ok, payload = query(session, keys.submit(STUDY), Submission(study=STUDY, jobs=jobs).to_bytes())
    assert ok and decode(SubmitReply, payload).queued == [job_id]


def _ask_worker(session: zenoh.Session, key: str) -> tuple[bool, bytes]:
    """(ok, payload) of the one answer to a small query on a worker's key."""
    (reply,) = session.get(key, timeout=10.0)
    if reply.ok is not None:
        return True, reply.ok.payload.to_bytes()
    return False, reply.err.payload.to_bytes()


def test_a_worker_drops_big_queries_on_its_log_keys_and_serves_on() -> None:
    assert FLOOD_MIB * 2**20 > SERVING_SESSION_BYTES
    calm = simulate(short_spec())
    results: dict[str, Result] = {}
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with (
        Broker([endpoint]) as broker,
        CobotWorker([endpoint], "w") as worker,
        open_session("client", connect=[endpoint]) as session,
    ):
        _token = open_study(session, broker, STUDY)
        _inbox = session.declare_subscriber(
            keys.study_results(STUDY),
            lambda sample: results.update(
                {(r := decode(Result, sample.attachment.to_bytes())).job_id: r}
            ),
        )
        stop = threading.Event()
        serving = threading.Thread(target=worker.serve, args=(stop,))
        serving.start()
        try:
            # The log the job makes, and one no worker has: a big query that reached the
            # worker would be answered either way (with the log, or with a refusal).
            kept, missing = keys.log(STUDY, "w", calm.digest), keys.log(STUDY, "w", "0" * 64)
            with flooding_keys(endpoint, FLOOD_MIB, ask=[kept, missing]) as counts:
                _submit(session, "during")
                wait_for(lambda: "during" in results, timeout=120, what="the job run in the flood")
                ok, content = _ask_worker(session, kept)  # small queries are served meanwhile
                assert ok and content == calm.content
                assert _ask_worker(session, missing) == (
                    False,
                    b"no such log: " + missing.encode() + b" (never made, or no longer kept)",
                )
            _submit(session, "after")
            wait_for(lambda: "after" in results, timeout=120, what="the job run after the flood")
        finally:
            stop.set()
            serving.join()
    assert counts.sent >= 2 and counts.answered == 0, counts
    for job_id in ("during", "after"):
        # The very log it makes without a flood (scores are the log's: the digest says it all).
        assert results[job_id].status == calm.status and results[job_id].digest == calm.digest
    print(f"{counts.sent} queries of {FLOOD_MIB} MiB sent, none answered")
