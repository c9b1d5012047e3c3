"""Big queries on the analytic process's model key (issue 47, item 4): a real flooder process
asks for the study's feed-forward model with payloads larger than any wire message while a real
`worker start` process fetches that model, larger than one part (PART_BYTES), for a real job.
Every session takes no message larger than SERVING_SESSION_BYTES, the broker's router included,
so Zenoh drops each big query on the way: none is answered (one that reached the client would
get an answer), the worker gets the model in parts, the job makes the log it makes without a
flood, and the client fetches that log in parts as it would without one."""

import itertools
from pathlib import Path

import numpy as np

from gainfarm.analytic.evaluators.evaluator import Wanted
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import free_port
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session
from gainfarm.models.dynamics import DynamicsModel, Network, digest, rigid_spec, to_bytes
from gainfarm.schemas import EpisodeSpec, TrajectorySpec, keys
from gainfarm.schemas.robot import IDEAL_PLANT
from gainfarm.schemas.wire import PART_BYTES
from gainfarm.worker.job import simulate
from gainfarm.worker.service import fetch_model
from tests.analytic.flooder import STUDY, farm_processes, flooding_keys
from tests.helpers import SOFT_GAINS

FLOOD_MIB = 8
RIGID_IDEAL = IDEAL_PLANT.model_copy(update={"joints": "rigid"})


def big_model(hidden: int = 600) -> DynamicsModel:
    """A residual model whose network adds nothing (zero weights), in a file of two parts."""
    widths = (21, hidden, hidden, 7)
    network = Network(
        weights=tuple(np.zeros((a, b)) for a, b in itertools.pairwise(widths)),
        biases=tuple(np.zeros(b) for b in widths[1:]),
        input_mean=np.zeros(21),
        input_scale=np.ones(21),
        output_mean=np.zeros(7),
        output_scale=np.ones(7),
    )
    return DynamicsModel("residual", "inverse", rigid_spec(RIGID_IDEAL), network=network)


def test_big_queries_on_the_model_key_are_dropped_and_the_model_still_served(
    tmp_path: Path,
) -> None:
    assert FLOOD_MIB * 2**20 > SERVING_SESSION_BYTES
    model = big_model()
    raw = to_bytes(model)
    assert PART_BYTES < len(raw) <= 2 * PART_BYTES
    trajectory = TrajectorySpec(kind="fourier", duration=0.5, seed=4)
    spec = EpisodeSpec(
        gains=SOFT_GAINS, trajectory=trajectory, plant=RIGID_IDEAL, feedforward=digest(raw)
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
        with open_session(
            "client", connect=[endpoint], max_message_bytes=SERVING_SESSION_BYTES
        ) as session:
            assert fetch_model(session, STUDY, digest(raw)) == raw  # and after it
        fetched = farm.fetch({"during": Wanted(spec, calm.digest, ("w",))})["during"]
    # Each big query went unanswered until the router gave up on it.
    assert counts.sent >= 2 and counts.answered == 0 and counts.timed_out >= 1, counts
    assert result.status.value == calm.status.value and result.digest == calm.digest
    assert fetched.digest == calm.digest and fetched.log.read_bytes() == calm.content
    print(f"{counts.sent} queries of {FLOOD_MIB} MiB sent, none answered")
