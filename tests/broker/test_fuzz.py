"""Fuzzing every key the broker and the analytic client listen to, over real Zenoh: whatever
arrives, each keeps serving, says why it refused, and no study's state changes."""

import json
from collections.abc import Iterator

import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from analytic.farm import FarmClient
from analytic.local import free_port
from broker.service import Broker
from schemas import keys
from schemas.transport import open_session
from schemas.wire import MAX_MESSAGE_BYTES, Job, LeaseRequest, Submission
from tests.helpers import short_spec, wait_for

PROTECTED = "protected-study"

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=10), children, max_size=4)
    ),
    max_leaves=12,
)
VALID = {
    keys.SUBMIT: Submission(study="fuzz", jobs=[Job(job_id="j", spec=short_spec())]),
    keys.LEASE: LeaseRequest(worker="fuzz-worker"),
}


def mutated(valid: dict) -> st.SearchStrategy[bytes]:
    """A valid message with one field, at any depth, replaced by an arbitrary JSON value."""
    paths: list[tuple] = []

    def walk(node: object, path: tuple) -> None:
        paths.append(path)
        if isinstance(node, dict):
            for key, value in node.items():
                walk(value, (*path, key))
        elif isinstance(node, list):
            for index, value in enumerate(node):
                walk(value, (*path, index))

    walk(valid, ())

    def replace(path: tuple, value: object) -> bytes:
        if not path:
            return json.dumps(value).encode()
        copy = json.loads(json.dumps(valid))
        node = copy
        for part in path[:-1]:
            node = node[part]
        node[path[-1]] = value
        return json.dumps(copy).encode()  # NaN and Infinity go out as JSON's non-standard tokens

    return st.builds(replace, st.sampled_from(paths[1:]), json_values)


def payloads(key: str) -> st.SearchStrategy[bytes]:
    return st.one_of(
        st.binary(max_size=300),
        json_values.map(lambda value: json.dumps(value).encode()),
        mutated(json.loads(VALID[key].to_bytes())),
        st.just(b"{" * (MAX_MESSAGE_BYTES + 1)),
    )


@pytest.fixture(scope="module")
def farm(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[Broker, zenoh.Session, FarmClient]]:
    """A broker, a fuzzing session, and a protected study with two queued jobs it must keep."""
    with Broker([f"tcp/127.0.0.1:{free_port()}"]) as broker:
        client = FarmClient(broker.endpoints, PROTECTED, tmp_path_factory.mktemp("run"))
        client.submit({"kept-1": short_spec(), "kept-2": short_spec()})
        fuzzer = open_session("client", connect=broker.endpoints)
        yield broker, fuzzer, client
        fuzzer.close()
        client.close()


def protected_state(broker: Broker) -> list:
    return [study for study in broker.queue.study_states() if study.name == PROTECTED]


FUZZ = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@pytest.mark.parametrize("key", [keys.SUBMIT, keys.LEASE])
@FUZZ
@given(data=st.data())
def test_the_broker_answers_anything_on_its_queryables(farm, key: str, data) -> None:
    broker, fuzzer, _ = farm
    before = protected_state(broker)
    payload = data.draw(payloads(key))
    replies = list(fuzzer.get(key, payload=payload, timeout=5.0))
    assert len(replies) == 1  # an answer, never silence
    reply = replies[0]
    if reply.ok is None:
        reason = reply.err.payload.to_bytes().decode()
        assert reason and "\n" not in reason
    assert protected_state(broker) == before
    assert broker.status().studies  # and it still serves


@FUZZ
@given(
    attachment=st.one_of(
        st.none(),
        st.binary(max_size=200),
        json_values.map(lambda value: json.dumps(value).encode()),
    ),
    payload=st.binary(max_size=200),
    job=st.from_regex(r"[a-z0-9]{1,12}", fullmatch=True),
)
def test_results_of_any_shape_do_not_disturb_a_study(
    farm, attachment: bytes | None, payload: bytes, job: str
) -> None:
    broker, fuzzer, client = farm
    before = protected_state(broker)
    heard = client.ignored + client.duplicates
    fuzzer.put(keys.result(PROTECTED, job), payload, attachment=attachment)

    def refused() -> bool:
        assert list(client.results(timeout=0.05)) == []  # nothing forged becomes an evaluation
        return client.ignored + client.duplicates > heard

    wait_for(refused, what="the client to refuse it")
    assert protected_state(broker) == before
    assert client.pending == 2
