"""The wire contract: every message decodes only when it is whole, current and valid."""

import json
import re
from dataclasses import fields, replace

import mujoco
import numpy as np
import pytest

from gainfarm.models.iiwa14 import FLANGE, compile_model
from gainfarm.schemas import json_schema
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR, LAG_CAP, score
from gainfarm.schemas.robot import IDEAL_PLANT, PLAIN_PLANT, PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.wire import (
    MAX_CONFIRM_JOBS,
    MAX_MESSAGE_BYTES,
    MAX_SUBMISSION_JOBS,
    MAX_TORQUE_CHANGE,
    MAX_TORQUE_SHARE,
    MAX_TRACKING_ERROR,
    MESSAGES,
    PROTOCOL_VERSION,
    Accepted,
    BadMessage,
    BrokerStatus,
    ConfirmReply,
    ConfirmRequest,
    Job,
    Lease,
    LeaseReply,
    LeaseRequest,
    Part,
    Rejection,
    Result,
    Submission,
    SubmitReply,
    WireScores,
    decode,
    decode_submission,
)
from gainfarm.worker.episode import run_episode
from tests.helpers import maximal_job, short_spec

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
        (b'{"protocol": %d}' % V, "worker: missing"),
        (b'{"protocol": %d, "worker": "a/b"}' % V, "worker: must match the pattern"),
        (
            b'{"protocol": %d, "worker": "w", "extra": 1}' % V,
            "unknown field 'extra'",
        ),
        (b" " * (MAX_MESSAGE_BYTES + 1), "over the limit"),
    ],
)
def test_a_bad_message_is_refused_with_its_reason(raw: bytes | None, reason: str) -> None:
    with pytest.raises(BadMessage, match=reason) as refused:
        decode(LeaseRequest, raw)
    assert "\n" not in str(refused.value)


OURS = b'"protocol":%d' % V
NOT_INTEGERS = [b"%d.0" % V, b"%de0" % V, b"%d.000001" % V, b'"%d"' % V, b"true", b"[%d]" % V]
NOT_INTEGERS.append(b'{"v": %d}' % V)


@pytest.mark.parametrize("kind", MESSAGES, ids=lambda kind: kind.__name__)
@pytest.mark.parametrize("version", NOT_INTEGERS, ids=lambda raw: raw.decode())
def test_the_protocol_version_is_an_integer_in_every_message(kind: type, version: bytes) -> None:
    # Before the schema is checked (the slow path) and after the fast one: both refuse it alike.
    for raw in (
        b'{"protocol": %s}' % version,
        honest_bytes(kind).replace(OURS, b'"protocol":' + version),
    ):
        assert version in raw
        with pytest.raises(BadMessage, match=r"protocol version .* is not an integer") as refused:
            decode(kind, raw)
        assert str(refused.value).startswith(f"{kind.__name__}: protocol version ")
        assert "\n" not in str(refused.value)


@pytest.mark.parametrize("version", NOT_INTEGERS, ids=lambda raw: raw.decode())
def test_a_submission_with_a_version_not_an_integer_is_refused_whole(version: bytes) -> None:
    raw = honest_bytes(Submission).replace(OURS, b'"protocol":' + version)
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
        Part: Part(total=3 * 2**20, part=1),
    }
    raw = examples[kind].to_bytes()
    assert raw.startswith(b"{" + OURS + b",") and decode(kind, raw) == examples[kind]
    return raw


def test_honest_examples_cover_every_message() -> None:
    for kind in MESSAGES:
        honest_bytes(kind)


def test_a_submission_is_judged_job_by_job() -> None:
    good = Job(job_id="good", spec=short_spec()).model_dump(mode="json")
    bad = {**good, "job_id": "bad", "spec": {"gains": {"kp": [1], "kd": [1, 2]}}}
    raw = json.dumps({"protocol": V, "study": "s", "jobs": [good, bad, 42]}).encode()
    study, jobs, rejected = decode_submission(raw)
    assert study == "s"
    assert [job.job_id for job in jobs] == ["good"]
    assert [rejection.job_id for rejection in rejected] == ["bad", "jobs[2]"]
    assert "spec.gains: kp has 1 gains and kd 2" in rejected[0].reason


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
    "torque_step": 0.01,
    "speed": 0.5,
    "chatter": 0.001,
    "lag": 0.006,
    "damping": 0.05,
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


def result_with_scores(**scores: object) -> bytes:
    fields = json.loads(honest_bytes(Result))
    return json.dumps({**fields, "scores": {**SCORES, **scores}}).encode()


@pytest.mark.parametrize(
    ("scores", "reason"),
    [
        ({"f_acc": -1e-9}, "scores.f_acc: must be at least 0"),
        ({"f_acc": -0.0}, "scores.f_acc: -0.0 is not a score"),
        ({"f_acc": 2.5}, "scores.f_acc: must be at most 2"),
        ({"f_t": -0.5}, "scores.f_t: must be at least 0"),
        ({"f_t": 1e300}, "scores.f_t: must be at most 1200000"),
        ({"max_error": -0.0}, "scores.max_error: -0.0 is not a score"),
        ({"max_error": 1e9}, "scores.max_error: must be at most 2"),
        ({"saturated_fraction": -3}, "scores.saturated_fraction: must be at least"),
        ({"saturated_fraction": 1.01}, "scores.saturated_fraction: must be at most"),
        ({"ticks": -5}, "scores.ticks: must be at least 0"),
        ({"torque_step": -0.0}, "scores.torque_step: -0.0 is not a score"),
        ({"torque_step": 2.0001}, "scores.torque_step: must be at most 2"),
        ({"speed": -1.0}, "scores.speed: must be at least 0"),
        ({"speed": 1000.5}, "scores.speed: must be at most 1000"),
        ({"speed": "Infinity"}, "scores.speed: must be a finite number"),
        ({"chatter": -0.0}, "scores.chatter: -0.0 is not a score"),
        ({"chatter": 2.5}, "scores.chatter: must be at most 2"),
        ({"chatter": None}, "scores.chatter: expected a number"),
        ({"lag": -0.0}, "scores.lag: -0.0 is not a score"),
        ({"lag": 7.0}, "scores.lag: must be at most 6.28"),
        ({"lag": -0.1}, "scores.lag: must be at least 0"),
        ({"lag": None}, "scores.lag: expected a number"),
        ({"damping": -0.0}, "scores.damping: -0.0 is not a score"),
        ({"damping": 1.5}, "scores.damping: must be at most 1"),
        ({"damping": -1.01}, "scores.damping: must be at least -1"),
        ({"damping": None}, "scores.damping: expected a number"),
        ({"torque_step": None, "speed": None}, "scores.torque_step: expected a number"),
        ({"ticks": 60_002}, "scores.ticks: must be at most 60001"),
        ({"values": [0.1, 1e999]}, "scores.values.1: must be a finite number"),
        ({"values": ["NaN", 0.1]}, "scores.values.0: must be a finite number"),
    ],
)
def test_scores_beyond_any_episodes_are_refused(scores: dict, reason: str) -> None:
    with pytest.raises(BadMessage, match=f"^Result: {re.escape(reason)}") as refused:
        decode(Result, result_with_scores(**scores))
    assert "\n" not in str(refused.value)
    request = json.loads(LeaseRequest(worker="w").to_bytes())
    request["results"] = [json.loads(result_with_scores(**scores))]
    with pytest.raises(BadMessage, match=re.escape(f"results.0.{reason}")):
        decode(LeaseRequest, json.dumps(request).encode())


def test_honest_scores_keep_their_json_on_the_wire() -> None:
    for values in (None, (-3.5, 0.0)):  # a plug-in's objective may be negative
        scores = Scores(**SCORES, values=values)
        assert WireScores(**scores.model_dump()).model_dump_json() == scores.model_dump_json()
    edge = {"f_acc": 0.0, "f_t": 0.0, "max_error": 0.0, "saturated_fraction": 1.0, "ticks": 0}
    edge |= {"torque_step": 2.0, "speed": 1000.0, "chatter": 0.0, "lag": LAG_CAP, "damping": -1.0}
    assert decode(Result, result_with_scores(**edge)).scores == WireScores(**{**SCORES, **edge})


def test_the_flange_never_strays_as_far_from_its_reference_as_the_bound() -> None:
    """Every position of the flange is within the links' offsets, added up, of the shoulder (A2,
    which stays put as A1 turns): no two of them, the arm's and its reference's, are farther
    apart than twice that."""
    model = compile_model(PlantSpec())
    data = mujoco.MjData(model)
    site, shoulder = model.site(FLANGE), model.body("link2").id
    reach, body = float(np.linalg.norm(site.pos)), int(site.bodyid[0])
    while body != shoulder:
        reach, body = reach + float(np.linalg.norm(model.body_pos[body])), model.body_parentid[body]
    assert 2 * reach < MAX_TRACKING_ERROR
    rng = np.random.default_rng(0)
    origin = None
    for _ in range(2000):  # anywhere, joint ranges or not: a diverging arm leaves them
        data.qpos[:] = rng.uniform(-np.pi, np.pi, model.nq)
        mujoco.mj_kinematics(model, data)
        origin = data.xpos[shoulder].copy() if origin is None else origin
        np.testing.assert_allclose(data.xpos[shoulder], origin, atol=1e-12)
        assert np.linalg.norm(data.site_xpos[site.id] - origin) <= reach + 1e-9
    assert np.isclose(reach, 0.946)  # the comment at MAX_TRACKING_ERROR says so


def test_no_episode_scores_beyond_the_wires_bounds(diverged_log: EpisodeLog) -> None:
    """The extremes: an arm that falls (diverged), one with no torque at all, gains that
    saturate every joint, and what no episode can reach: every tick a swing from limit to limit
    at the far side of the workspace, and an episode cut short before its first tick."""
    short = TrajectorySpec(duration=3.0)
    zero = PDGains(kp=(0,) * 7, kd=(0,) * 7)
    aggressive = PDGains(kp=(1e6,) * 7, kd=(1e4,) * 7)
    logs = [
        diverged_log,
        run_episode(EpisodeSpec(gains=zero, trajectory=short, plant=PLAIN_PLANT)),
        run_episode(EpisodeSpec(gains=aggressive, trajectory=short, plant=IDEAL_PLANT)),
    ]
    assert logs[0].metadata.diverged and logs[1].metadata.diverged
    assert score(logs[2]).saturated_fraction > 0.5, score(logs[2])
    limits = np.asarray(diverged_log.metadata.torque_limits)
    swing = np.where(np.arange(diverged_log.ticks)[:, None] % 2, limits, -limits)
    far = np.array([0.946, 0.0, 0.36])  # the flange, and its reference across the shoulder
    worst = replace(
        diverged_log,
        u=swing,
        ee=np.tile(far, (diverged_log.ticks, 1)),
        ee_des=np.tile(far * [-1, 1, 1], (diverged_log.ticks, 1)),
    )
    cut = replace(diverged_log, **{name: column[:0] for name, column in columns(diverged_log)})
    logs += [worst, cut]
    for log in logs:
        scores = score(log)
        assert WireScores(**scores.model_dump()) == WireScores.model_validate(scores.model_dump())
    assert score(cut).f_acc == DIVERGED_TICK_ERROR and score(cut).ticks == 0
    swing_every_tick = sum((2 * limit) ** 2 for limit in limits)
    assert 0.999 * swing_every_tick < score(worst).f_t <= swing_every_tick < MAX_TORQUE_CHANGE
    assert score(cut).f_t == swing_every_tick
    assert score(worst).max_error == pytest.approx(2 * 0.946)
    assert score(worst).torque_step == MAX_TORQUE_SHARE  # limit to limit, exactly
    assert 0.9 < score(worst).chatter <= MAX_TORQUE_SHARE  # all of it above the cut-off
    assert score(cut).torque_step == score(cut).speed == score(cut).chatter == 0.0
    assert score(logs[2]).speed > 1 and score(logs[2]).chatter > 0.05  # saturating gains


def test_scores_without_the_safety_measures_are_refused_on_the_wire() -> None:
    """A worker of protocol 6 sent none, one of protocol 8 no lag: this protocol's always
    measures them."""
    for name in ("torque_step", "speed", "chatter", "lag"):
        old = {key: value for key, value in SCORES.items() if key != name}
        with pytest.raises(BadMessage, match=f"^Result: scores.{name}: missing"):
            decode(Result, json.dumps({**json.loads(result_with_scores()), "scores": old}).encode())


def columns(log: EpisodeLog) -> list[tuple[str, np.ndarray]]:
    return [(f.name, getattr(log, f.name)) for f in fields(log) if f.name != "metadata"]


# --- sizes: every message of the bounds fits in MAX_MESSAGE_BYTES -------------------------------


def test_no_field_of_a_submission_is_unbounded() -> None:
    """Every list has a longest, every string a pattern or a length, every integer a maximum:
    with floats at most 24 characters, a Job has a largest JSON (tests.helpers.maximal_job)."""
    schema = Submission.model_json_schema()
    unbounded = []

    def walk(node: object, where: str) -> None:
        if isinstance(node, dict):
            kind = node.get("type")
            if kind == "array" and "maxItems" not in node and "prefixItems" not in node:
                unbounded.append(where)
            if kind == "string" and not {"pattern", "maxLength", "enum", "const"} & set(node):
                unbounded.append(where)
            if kind == "integer" and not {"maximum", "exclusiveMaximum", "const"} & set(node):
                unbounded.append(where)
            for key, value in node.items():
                walk(value, f"{where}.{key}")
        elif isinstance(node, list):
            for index, value in enumerate(node):
                walk(value, f"{where}[{index}]")

    walk(schema, "Submission")
    assert unbounded == []


def test_the_largest_submission_fits_in_a_message() -> None:
    job = maximal_job()
    assert 6000 < len(job.model_dump_json()) < 7000  # the 6.5 kB MAX_SUBMISSION_JOBS is sized by
    jobs = [maximal_job(n) for n in range(MAX_SUBMISSION_JOBS)]
    largest = Submission(study="s" * 64, jobs=jobs).to_bytes()
    assert len(largest) <= MAX_MESSAGE_BYTES
    assert decode_submission(largest) == ("s" * 64, jobs, [])
    one_more = largest[:-2] + b"," + job.model_dump_json().encode() + b"]}"
    assert len(one_more) == len(largest) + len(job.model_dump_json()) + 1
    reason = (
        f"Submission: jobs: {MAX_SUBMISSION_JOBS + 1} items, at most {MAX_SUBMISSION_JOBS} allowed"
    )
    with pytest.raises(BadMessage, match=f"^{re.escape(reason)}"):
        decode_submission(one_more)
    with pytest.raises(BadMessage, match=f"^{re.escape(reason)}"):
        decode(Submission, one_more)


def test_the_reply_to_the_largest_submission_fits_whatever_its_jobs_say() -> None:
    """Each rejection quotes the job's id only if it is a name, and a reason of 300 characters
    at most, each escaped to six bytes at worst."""
    huge = "/" * 8000  # as long as 500 of them can be in a message
    raw = json.dumps(
        {"protocol": V, "study": "s", "jobs": [{"job_id": huge}] * MAX_SUBMISSION_JOBS}
    ).encode()
    _, jobs, rejected = decode_submission(raw)
    assert (
        len(raw) <= MAX_MESSAGE_BYTES
        and not jobs
        and [r.job_id for r in rejected[:2]] == ["jobs[0]", "jobs[1]"]
    )
    assert "job_id: must match the pattern" in rejected[0].reason
    worst = SubmitReply(
        study="s" * 64,
        rejected=[
            Rejection(job_id=f"jobs[{n}]", reason="\x01" * 300) for n in range(MAX_SUBMISSION_JOBS)
        ],
    )
    assert len(worst.to_bytes()) <= MAX_MESSAGE_BYTES
    named = json.dumps({"protocol": V, "study": "s", "jobs": [{"job_id": "j-1"}]}).encode()
    assert [r.job_id for r in decode_submission(named)[2]] == ["j-1"]


def test_the_largest_confirmation_and_its_reply_fit_in_a_message() -> None:
    names = [f"{n:064d}" for n in range(MAX_CONFIRM_JOBS)]
    request = ConfirmRequest(study="s" * 64, job_ids=names).to_bytes()
    assert len(request) <= MAX_MESSAGE_BYTES
    with pytest.raises(
        BadMessage,
        match=f"job_ids: {MAX_CONFIRM_JOBS + 1} items, at most {MAX_CONFIRM_JOBS} allowed",
    ):
        decode(ConfirmRequest, request.replace(b'"]}', b'","' + b"j" * 64 + b'"]}'))
    tiny = 2.2250738585072014e-308
    worst = {"f_acc": tiny, "f_t": tiny, "max_error": tiny, "saturated_fraction": tiny}
    worst |= {"torque_step": tiny, "speed": tiny, "chatter": tiny, "lag": tiny, "damping": -tiny}
    scores = WireScores(**{**SCORES, **worst, "values": (-tiny, -tiny), "ticks": 60_001})
    accepted = [
        Accepted(job_id=name, lease_id="l" * 64, worker="w" * 64, digest="f" * 64, scores=scores)
        for name in names
    ]
    assert len(ConfirmReply(study="s" * 64, accepted=accepted).to_bytes()) <= MAX_MESSAGE_BYTES
