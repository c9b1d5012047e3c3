"""Big queries on the broker's keys (issue 47, item 4): a real flooder process asks on submit,
lease and confirm with payloads larger than any wire message while a real `worker start`
process runs real jobs. Big bytes move in parts (schemas.parts), so the broker's router takes no
message larger than a wire message (SERVING_SESSION_BYTES): it drops each big query while
reassembling it, and the query never reaches the broker's code (no answer, nothing counted or
logged), while the study and the worker are served as without a flood."""

from pathlib import Path

from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.status import query_status
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session
from gainfarm.schemas import keys
from gainfarm.worker.job import simulate
from tests.analytic.flooder import STUDY, Study, farm_processes, flooding_keys
from tests.helpers import short_spec

FLOOD_MIB = 8


def test_the_broker_never_reassembles_big_queries_and_serves_on(tmp_path: Path) -> None:
    assert FLOOD_MIB * 2**20 > SERVING_SESSION_BYTES
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
    # No big query was answered, not even refused: the router dropped each one on the way and
    # the flooder's queries timed out; the broker's queryables never saw them.
    assert counts.sent >= 3 and counts.answered == 0 and counts.timed_out >= 1, counts
    assert rejected == 0
    assert "over the limit" not in broker_log.read_text()
    for result in (during, after):
        assert result.status == calm.status and result.digest == calm.digest
    print(f"{counts.sent} queries of {FLOOD_MIB} MiB sent, none reached the broker")
