"""Fuzzing every key the broker and the analytic client listen to, over real Zenoh: whatever
arrives, each keeps serving, says why it refused, and no study's state changes."""

import hashlib
import json
from collections.abc import Callable, Iterator

import pytest
import zenoh
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import free_port
from gainfarm.broker.service import Broker
from gainfarm.edges.ask import ask
from gainfarm.edges.transport import open_session
from gainfarm.schemas import keys
from gainfarm.schemas.wire import (
    MAX_MESSAGE_BYTES,
    BrokerStatus,
    ConfirmReply,
    ConfirmRequest,
    Job,
    LeaseReply,
    LeaseRequest,
    Submission,
    SubmitReply,
    WireMessage,
    decode,
)
from tests.helpers import result_for, short_spec, wait_for

PROTECTED = "protected-study"
FUZZ_STUDY = "fuzz"  # open: a submission that happens to be valid queues its jobs here
# Lease requests come from these names; the protected jobs avoid them, so that a request that
# happens to be valid cannot take one.
FUZZ_WORKERS = ("fuzz-worker", "stranger")

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


class Service:
    """One of the broker's queryables: its key for a name, the names a fuzzed key may carry,
    a valid message to mutate, and the kind of its answer."""

    def __init__(
        self,
        key: Callable[[str], str],
        names: tuple[str, ...],
        valid: WireMessage | None,
        answer: type[WireMessage],
    ):
        self.key, self.names, self.valid, self.answer = key, names, valid, answer


FORGED = result_for(PROTECTED, "kept-1", worker="fuzz-worker", lease_id="forged")
SERVICES = {
    "submit": Service(
        keys.submit,
        (FUZZ_STUDY, PROTECTED),
        Submission(study=FUZZ_STUDY, jobs=[Job(job_id="j", spec=short_spec())]),
        SubmitReply,
    ),
    "lease": Service(keys.lease, FUZZ_WORKERS, LeaseRequest(worker="fuzz-worker"), LeaseReply),
    "hand-in": Service(
        keys.lease,
        FUZZ_WORKERS,
        LeaseRequest(worker="fuzz-worker", want=0, results=[FORGED]),
        LeaseReply,
    ),
    "confirm": Service(
        keys.confirm,
        (PROTECTED, FUZZ_STUDY),
        ConfirmRequest(study=PROTECTED, job_ids=["kept-1", "kept-2"]),
        ConfirmReply,
    ),
    "status": Service(lambda _: keys.STATUS, ("",), None, BrokerStatus),
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


def payloads(valid: WireMessage | None) -> st.SearchStrategy[bytes | None]:
    anything = [
        st.none(),
        st.binary(max_size=300),
        json_values.map(lambda value: json.dumps(value).encode()),
        st.just(b"{" * (MAX_MESSAGE_BYTES + 1)),
        st.sampled_from([b"[" * 100_000, b'{"a":' * 100_000]),
    ]
    if valid is not None:
        anything += [st.just(valid.to_bytes()), mutated(json.loads(valid.to_bytes()))]
    return st.one_of(*anything)


@pytest.fixture(scope="module")
def farm(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[Broker, zenoh.Session, FarmClient]]:
    """A broker, a fuzzing session, and a protected study with two queued jobs it must keep."""
    with Broker([f"tcp/127.0.0.1:{free_port()}"]) as broker:
        client = FarmClient(broker.endpoints, PROTECTED, tmp_path_factory.mktemp("run"))
        kept = ["kept-1", "kept-2"]
        client.submit(
            {job_id: short_spec() for job_id in kept},
            avoid={job_id: FUZZ_WORKERS for job_id in kept},
        )
        fuzzer = open_session("client", connect=broker.endpoints)
        _study = fuzzer.liveliness().declare_token(keys.alive_study(FUZZ_STUDY))
        wait_for(
            lambda: any(study.name == FUZZ_STUDY for study in broker.queue.study_states()),
            what="the fuzz study to open",
        )
        yield broker, fuzzer, client
        fuzzer.close()
        client.close()


def protected_state(broker: Broker) -> list:
    return [study for study in broker.queue.study_states() if study.name == PROTECTED]


def still_serving(broker: Broker, session: zenoh.Session) -> None:
    """The broker answers a status query over the wire, and still has the protected study."""
    answer = ask(session, keys.STATUS, timeout=5.0)
    assert answer is not None and answer.payload is not None
    assert PROTECTED in {study.name for study in decode(BrokerStatus, answer.payload).studies}


FUZZ = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@pytest.mark.parametrize("service", SERVICES.values(), ids=SERVICES.keys())
@FUZZ
@given(data=st.data())
def test_the_broker_answers_anything_on_its_queryables(farm, service: Service, data) -> None:
    broker, fuzzer, _ = farm
    before = protected_state(broker)
    key = service.key(data.draw(st.sampled_from(service.names), label="name"))
    payload = data.draw(payloads(service.valid), label="payload")
    replies = list(fuzzer.get(key, payload=payload, timeout=5.0))
    assert len(replies) == 1  # an answer, never silence, and only one
    reply = replies[0]
    assert reply.replier_id is not None and reply.replier_id.zid == broker.session.zid()
    if reply.ok is None:
        reason = reply.err.payload.to_bytes().decode()
        assert reason and "\n" not in reason and reason != "Timeout"
        event("refused")
    else:
        answer = decode(service.answer, reply.ok.payload.to_bytes())  # a well-formed answer
        event(f"answered with a {type(answer).__name__}")
        if isinstance(answer, LeaseReply):
            # Nobody but a lease's holder knows its id; the protected jobs avoid the fuzzer.
            assert not any(verdict.accepted for verdict in answer.verdicts)
            assert all(lease.study == FUZZ_STUDY for lease in answer.leases)
        if isinstance(answer, ConfirmReply):
            assert answer.accepted == []  # nothing was handed in
    assert protected_state(broker) == before
    still_serving(broker, fuzzer)


def forged_results() -> st.SearchStrategy[tuple[str, bytes | None, bytes]]:
    """(job id in the key, attachment, payload) of a result sample: anything, or a well-made
    forgery whose digest is its log's, for a job the protected study waits for."""
    content = st.binary(max_size=200)
    kept = st.sampled_from(["kept-1", "kept-2"])

    def well_made(job_id: str, worker: str, lease_id: str, log: bytes) -> tuple:
        digest = hashlib.sha256(log).hexdigest()
        forged = result_for(
            PROTECTED,
            job_id,
            worker=worker,
            lease_id=lease_id,
            digest=digest,
            episode_bytes=len(log),
        )
        return job_id, forged.to_bytes(), log

    return st.one_of(
        st.tuples(
            kept | st.from_regex(r"[a-z0-9]{1,12}", fullmatch=True),
            st.one_of(
                st.none(),
                st.binary(max_size=200),
                json_values.map(lambda value: json.dumps(value).encode()),
                mutated(json.loads(FORGED.to_bytes())),
            ),
            content,
        ),
        st.builds(
            well_made,
            kept,
            st.sampled_from([*FUZZ_WORKERS, "local-0"]),
            st.from_regex(r"[A-Za-z0-9_\-]{1,22}", fullmatch=True),
            content,
        ),
    )


@FUZZ
@given(sample=forged_results())
@pytest.mark.slow
def test_results_of_any_shape_do_not_disturb_a_study(
    farm, sample: tuple[str, bytes | None, bytes]
) -> None:
    broker, fuzzer, client = farm
    job, attachment, payload = sample
    before = protected_state(broker)

    def heard() -> tuple[int, int, int]:
        return client.ignored, client.duplicates, client.unconfirmed

    earlier = heard()
    fuzzer.put(keys.result(PROTECTED, job), payload, attachment=attachment)

    def refused() -> bool:
        assert list(client.results(timeout=0.05)) == []  # nothing forged becomes an evaluation
        return heard() != earlier

    wait_for(refused, what="the client to refuse it")
    how = zip(("ignored", "a duplicate", "not confirmed"), heard(), earlier, strict=True)
    event(f"refused: {', '.join(what for what, now, then in how if now > then)}")
    assert protected_state(broker) == before
    assert client.pending == 2
    still_serving(broker, fuzzer)
