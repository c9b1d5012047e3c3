"""Big queries on the broker's keys (issue 47, item 4): a real flooder process asks on submit,
lease and confirm with payloads larger than any wire message while a real worker runs a real
job. The broker's router must take messages as large as an episode log (it forwards them), so
the queries reach the broker: each is refused by its size before its bytes are copied out of
Zenoh, and counted, while the honest study and worker are served as without a flood."""

import logging
import threading

import pytest
import zenoh

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.service import Broker
from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.wire import MAX_MESSAGE_BYTES, Job, Result, Submission, SubmitReply, decode
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


def test_the_broker_refuses_big_queries_by_their_size_and_serves_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="gainfarm.broker")
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
        flooded = [keys.submit(STUDY), keys.lease("w"), keys.confirm(STUDY)]
        try:
            with flooding_keys(endpoint, FLOOD_MIB, ask=flooded) as counts:
                _submit(session, "during")
                wait_for(lambda: "during" in results, timeout=120, what="the job run in the flood")
                wait_for(lambda: broker.rejected >= 3, timeout=60, what="a refusal on every key")
            _submit(session, "after")
            wait_for(lambda: "after" in results, timeout=120, what="the job run after the flood")
        finally:
            stop.set()
            serving.join()
        rejected = broker.rejected
    # Every big query that was answered was refused, each counted by the broker, and the
    # honest worker's lease requests on the flooded lease key were served all along.
    assert counts.sent >= 3 and counts.answered == counts.refused >= 3, counts
    assert rejected >= counts.refused
    # Refused by the payload's size before its bytes were copied out of Zenoh (the decoder's
    # own size check, after the copy, says which message it is, and not "not read").
    too_big = f"over the limit of {MAX_MESSAGE_BYTES}: not read"
    refused_on = {str(r.args[0]) for r in caplog.records if too_big in r.getMessage()}
    assert refused_on == set(flooded)
    for job_id in ("during", "after"):
        assert results[job_id].status == calm.status and results[job_id].digest == calm.digest
    print(f"{counts.sent} queries of {FLOOD_MIB} MiB sent, {counts.refused} refused by size")
