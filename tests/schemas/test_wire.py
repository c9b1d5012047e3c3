"""The wire contract: every message decodes only when it is whole, current and valid."""

import json

import pytest

from gainfarm.schemas import json_schema
from gainfarm.schemas.wire import (
    MAX_MESSAGE_BYTES,
    MESSAGES,
    PROTOCOL_VERSION,
    BadMessage,
    BrokerStatus,
    ConfirmReply,
    ConfirmRequest,
    Job,
    Lease,
    LeaseReply,
    LeaseRequest,
    Result,
    Submission,
    SubmitReply,
    decode,
    decode_submission,
)
from tests.helpers import short_spec

V = PROTOCOL_VERSION


def test_json_schema_files_are_generated_from_the_current_models() -> None:
    assert json_schema.stale() == [], "run: python -m gainfarm.schemas.json_schema"


def test_every_message_carries_the_protocol_version() -> None:
    for name, content in json_schema.rendered().items():
        assert json.loads(content)["properties"]["protocol"]["const"] == PROTOCOL_VERSION, name


def test_a_message_round_trips() -> None:
    submission = Submission(study="s", jobs=[Job(job_id="j1", spec=short_spec())])
    assert decode(Submission, submission.to_bytes()) == submission


@pytest.mark.parametrize(
    ("raw", "reason"),
    [
        (None, "empty message"),
        (b"{not json", "not JSON"),
        (b"\xff\xfe", "not JSON"),
        (b"[1, 2]", "not a JSON object"),
        (b'{"worker": "w"}', f"protocol version None is not {V}"),
        (b'{"protocol": 1, "worker": "w"}', f"protocol version 1 is not {V}"),
        (b'{"protocol": 2, "worker": "w"}', f"protocol version 2 is not {V}"),
        (b'{"protocol": true, "worker": "w"}', "protocol version True is not an integer"),
        (b'{"protocol": %d}' % V, "worker: Field required"),
        (b'{"protocol": %d, "worker": "a/b"}' % V, "worker: String should match pattern"),
        (
            b'{"protocol": %d, "worker": "w", "extra": 1}' % V,
            "extra: Extra inputs are not permitted",
        ),
        (b" " * (MAX_MESSAGE_BYTES + 1), "over the limit"),
    ],
)
def test_a_bad_message_is_refused_with_its_reason(raw: bytes | None, reason: str) -> None:
    with pytest.raises(BadMessage, match=reason) as refused:
        decode(LeaseRequest, raw)
    assert "\n" not in str(refused.value)


NOT_INTEGERS = [b"6.0", b"6e0", b"6.000001", b'"6"', b"true", b"[6]", b'{"v": 6}']


@pytest.mark.parametrize("kind", MESSAGES, ids=lambda kind: kind.__name__)
@pytest.mark.parametrize("version", NOT_INTEGERS, ids=lambda raw: raw.decode())
def test_the_protocol_version_is_an_integer_in_every_message(kind: type, version: bytes) -> None:
    # Before the schema is checked (the slow path) and after the fast one: both refuse it alike.
    for raw in (
        b'{"protocol": %s}' % version,
        honest_bytes(kind).replace(b'"protocol":6', b'"protocol":' + version),
    ):
        assert version in raw
        with pytest.raises(BadMessage, match=r"protocol version .* is not an integer") as refused:
            decode(kind, raw)
        assert str(refused.value).startswith(f"{kind.__name__}: protocol version ")
        assert "\n" not in str(refused.value)


@pytest.mark.parametrize("version", NOT_INTEGERS, ids=lambda raw: raw.decode())
def test_a_submission_with_a_version_not_an_integer_is_refused_whole(version: bytes) -> None:
    raw = honest_bytes(Submission).replace(b'"protocol":6', b'"protocol":' + version)
    with pytest.raises(BadMessage, match=r"^Submission: protocol version .* is not an integer"):
        decode_submission(raw)
    nested = Result.model_validate_json(honest_bytes(Result)).model_dump(mode="json")
    request = {
        "protocol": V,
        "worker": "w",
        "results": [{**nested, "protocol": json.loads(version)}],
    }
    with pytest.raises(BadMessage, match=r"results\.0\.protocol: .*is not an integer"):
        decode(LeaseRequest, json.dumps(request).encode())


def honest_bytes(kind: type) -> bytes:
    """A valid message of `kind`, its version at the front as every sender writes it."""
    job = Job(job_id="j1", spec=short_spec())
    examples = {
        Submission: Submission(study="s", jobs=[job]),
        SubmitReply: SubmitReply(study="s", queued=["j1"]),
        LeaseRequest: LeaseRequest(worker="w"),
        LeaseReply: LeaseReply(leases=[Lease(lease_id="l", study="s", job=job, expires_in=1.0)]),
        Result: Result(
            study="s",
            job_id="j1",
            lease_id="l",
            worker="w",
            status="ok",
            episode_bytes=0,
            digest="0" * 64,
            timings={"simulate_s": 0.1, "encode_s": 0.0},
            scores=SCORES,
        ),
        ConfirmRequest: ConfirmRequest(study="s", job_ids=["j1"]),
        ConfirmReply: ConfirmReply(study="s"),
        BrokerStatus: BrokerStatus(
            uptime_s=1.0,
            workers=[],
            studies=[],
            jobs_done=0,
            jobs_per_s=0.0,
            requeued=0,
            rejected=0,
        ),
    }
    raw = examples[kind].to_bytes()
    assert raw.startswith(b'{"protocol":6,') and decode(kind, raw) == examples[kind]
    return raw


def test_honest_examples_cover_every_message() -> None:
    for kind in MESSAGES:
        honest_bytes(kind)


def test_a_submission_is_judged_job_by_job() -> None:
    good = Job(job_id="good", spec=short_spec()).model_dump(mode="json")
    bad = {**good, "job_id": "bad", "spec": {"gains": {"kp": [1], "kd": [1]}}}
    raw = json.dumps({"protocol": V, "study": "s", "jobs": [good, bad, 42]}).encode()
    study, jobs, rejected = decode_submission(raw)
    assert study == "s"
    assert [job.job_id for job in jobs] == ["good"]
    assert [rejection.job_id for rejection in rejected] == ["bad", "jobs[2]"]
    assert "spec.gains.kp" in rejected[0].reason


def test_a_submission_with_a_bad_envelope_is_refused_whole() -> None:
    with pytest.raises(BadMessage, match="study"):
        decode_submission(b'{"protocol": %d, "study": "no/slashes", "jobs": []}' % V)


SCORES = {
    "f_acc": 0.01,
    "f_t": 0.2,
    "max_error": 0.03,
    "saturated_fraction": 0.0,
    "diverged": False,
    "ticks": 10,
}


def test_a_result_carries_scores_exactly_when_its_episode_ran() -> None:
    fields = dict(
        study="s",
        job_id="j",
        lease_id="l",
        worker="w",
        episode_bytes=0,
        digest="0" * 64,
        timings={"simulate_s": 0.1, "encode_s": 0.0},
    )
    ran = Result(**fields, status="ok", scores=SCORES)
    assert decode(Result, ran.to_bytes()) == ran  # exact floats both ways
    Result(**fields, status="failed")
    for status, scores in (("ok", None), ("diverged", None), ("failed", SCORES)):
        with pytest.raises(ValueError, match="scores: required for an episode that ran"):
            Result(**fields, status=status, scores=scores)
    for bad in (float("nan"), float("inf")):
        with pytest.raises(ValueError, match="f_acc"):
            Result(**fields, status="ok", scores={**SCORES, "f_acc": bad})
    raw = ran.to_bytes().replace(b'"ticks":10', b'"ticks":10,"extra":1')
    with pytest.raises(BadMessage, match="extra"):
        decode(Result, raw)


def test_a_result_names_must_be_key_safe() -> None:
    fields = dict(
        study="s",
        job_id="j",
        lease_id="l",
        worker="w",
        status="ok",
        episode_bytes=0,
        digest="0" * 64,
        timings={"simulate_s": 0.1, "encode_s": 0.0},
        scores=SCORES,
    )
    Result(**fields)
    with pytest.raises(ValueError, match="digest"):
        Result(**{**fields, "digest": "not a sha-256"})
    with pytest.raises(ValueError, match="job_id"):
        Result(**{**fields, "job_id": "j/*"})
