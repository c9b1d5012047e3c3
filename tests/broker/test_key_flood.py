"""Big queries on the broker's keys (issue 47, item 4): a real flooder process asks on submit,
lease and confirm with payloads larger than any wire message while a real `worker start`
process runs real jobs. The broker's router must take messages as large as an episode log (it
forwards them), so the queries reach the broker: each is refused by its size before its bytes
are copied out of Zenoh, counted and logged, while the study and the worker are served as
without a flood."""

from pathlib import Path

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.status import query_status
from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.wire import MAX_MESSAGE_BYTES
from gainfarm.worker.job import simulate
from tests.analytic.flooder import STUDY, Study, farm_processes, flooding_keys
from tests.helpers import short_spec

FLOOD_MIB = 8


def test_the_broker_refuses_big_queries_by_their_size_and_serves_on(tmp_path: Path) -> None:
    calm = simulate(short_spec())
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    broker_log = tmp_path / "broker.log"
    flooded = [keys.submit(STUDY), keys.lease("w"), keys.confirm(STUDY)]
    with (
        farm_processes(endpoint, ["w"], broker_log),
        open_session("client", connect=[endpoint]) as session,
    ):
        study = Study(session)
        with flooding_keys(endpoint, FLOOD_MIB, ask=flooded) as counts:
            during = study.run("during")  # the worker's lease requests on the flooded key too
        after = study.run("after")
        rejected = query_status(session).rejected
    # Every big query answered was refused, each counted by the broker.
    assert counts.sent >= 3 and counts.answered == counts.refused >= 3, counts
    assert rejected >= counts.refused
    # Refused by the payload's size before its bytes were copied out of Zenoh (the decoder's
    # own size check, after the copy, names the message and does not say "not read").
    too_big = f"over the limit of {MAX_MESSAGE_BYTES}: not read"
    lines = [line for line in broker_log.read_text().splitlines() if too_big in line]
    assert len(lines) >= counts.refused
    assert {key for key in flooded if any(f" on {key}: " in line for line in lines)} == set(flooded)
    for result in (during, after):
        assert result.status == calm.status and result.digest == calm.digest
    print(f"{counts.sent} queries of {FLOOD_MIB} MiB sent, {counts.refused} refused by size")
