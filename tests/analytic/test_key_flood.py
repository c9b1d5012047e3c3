"""Big queries on the analytic process's model key (issue 47, item 4): a real flooder process
asks for the study's feed-forward model with payloads larger than any wire message while a real
`worker start` process fetches that model for a real job. The FarmClient serves models on a
session that takes no message larger than SERVING_SESSION_BYTES, so Zenoh drops each big query
on the way: none is answered (one that reached the client would get the model), the worker gets
the model, the job makes the log it makes without a flood, and the client fetches that log (on
a session of its own, which takes logs) as it would without one."""

from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import Wanted
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import free_port
from gainfarm.edges.transport import SERVING_SESSION_BYTES
from gainfarm.models.dynamics import digest, rigid_prior, to_bytes
from gainfarm.schemas import EpisodeSpec, TrajectorySpec, keys
from gainfarm.schemas.robot import IDEAL_PLANT
from gainfarm.worker.job import simulate
from gainfarm.worker.service import fetch_model
from tests.analytic.flooder import STUDY, farm_processes, flooding_keys
from tests.helpers import SOFT_GAINS

FLOOD_MIB = 8
RIGID_IDEAL = IDEAL_PLANT.model_copy(update={"joints": "rigid"})


def test_big_queries_on_the_model_key_are_dropped_and_the_model_still_served(
    tmp_path: Path,
) -> None:
    assert FLOOD_MIB * 2**20 > SERVING_SESSION_BYTES
    model = rigid_prior(RIGID_IDEAL)
    raw = to_bytes(model)
    trajectory = TrajectorySpec(kind="fourier", duration=0.5, seed=4)
    spec = EpisodeSpec(
        gains=SOFT_GAINS, trajectory=trajectory, model=RIGID_IDEAL, feedforward=digest(raw)
    )
    calm = simulate(spec, lambda _: model)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with (
        farm_processes(endpoint, ["w"], tmp_path / "broker.log"),
        FarmClient(
            [endpoint], STUDY, tmp_path / "run", models={digest(raw): raw}, keep_logs=False
        ) as farm,
    ):
        with flooding_keys(endpoint, FLOOD_MIB, ask=[keys.model(STUDY, digest(raw))]) as counts:
            farm.submit({"during": spec})  # its worker fetches the model in the flood
            (result,) = farm.results(timeout=120)
        assert fetch_model([endpoint], None, STUDY, digest(raw)) == raw  # and after it
        fetched = farm.fetch({"during": Wanted(spec, calm.digest, ("w",))})["during"]
    # Each big query went unanswered until the router gave up on it.
    assert counts.sent >= 2 and counts.answered == 0 and counts.timed_out >= 1, counts
    assert result.status.value == calm.status.value and result.digest == calm.digest
    assert fetched.digest == calm.digest and fetched.log.read_bytes() == calm.content
    print(f"{counts.sent} queries of {FLOOD_MIB} MiB sent, none answered")
