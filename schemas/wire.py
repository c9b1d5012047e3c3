"""The farm's messages: what travels between analytic processes, the broker and the workers.

Every message is JSON and carries `protocol`. `decode` is the one way in: it checks size, JSON,
protocol version and schema, and says in one line what was wrong, so that every listener can
reject a bad message with a reason and go on serving. The key expressions are in schemas.keys.
"""

import json
import math
import re
from collections.abc import Iterable
from enum import StrEnum
from typing import Annotated, Literal, TypeVar

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import ErrorDetails

from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.objectives import LAG_CAP, SPEED_CAP
from gainfarm.schemas.trajectory import CONTROL_PERIOD, MAX_DURATION

# 12: any arm: a plant's per-joint numbers (stiffness, spring_damping, rotor_inertia, friction,
# mass_scale) may be left null, the robot's own (a stiffness may name its preset), as many as the
# robot has joints, and its inertial set is any of the robot's; gains are one Kp and Kd per joint
# of the robot. A worker writes the plant out before it runs (models.resolve) and refuses a job
# its robot cannot be, with the reason.
# 11: a plant names its robot (PlantSpec.robot), a gainfarm.robots plug-in's name of its form, no
# longer only "iiwa14": a worker that lacks the robot a job names refuses it (JobStatus.refused);
# a job on the iiwa 14 has the same JSON as in 10.
# 10: big bytes (an episode log, a model) move only in parts of at most PART_BYTES: a log or
# model query names its part (`?part=N`) and the reply carries it with a Part attachment; a
# Result's sample never carries its log (the study fetches it in parts from its worker, which keeps
# every log it made; Job.keep_log says the study will).
# 9: scores carry the worst joint's RMS lag behind its reference (Scores.lag; schemas.limits).
# 8: scores carry the closed loop's least damping ratio (Scores.damping; worker.stability), from
# the log's metadata.
# 7: scores carry the safety measures (Scores.torque_step, speed, chatter; schemas.limits).
# 6: plug-ins: a trajectory kind is any name of its form, a job may name its objectives
# (EpisodeSpec.objectives) and its scores then carry their values (Scores.values), and a worker
# that lacks a plug-in the job names refuses it (JobStatus.refused); a job of the built-in kinds
# and objectives has the same JSON as in 5. 5: leases in batches, results handed in with the next
# lease request; 4: results carry the worker's scores, and the log only when the job asks to keep
# it (the worker keeps the others, to be fetched); 3: results handed in to the broker and
# confirmed by it; 2: Job.spec
PROTOCOL_VERSION = 12

# Names become key-expression chunks, so they may not contain '/', '*', '$', '?' or '#'.
NAME_PATTERN = r"^[A-Za-z0-9_.\-]{1,64}$"
NAME_RULE = "1 to 64 letters, digits, '_', '.' or '-'"
Name = Annotated[str, Field(pattern=NAME_PATTERN)]

# The broker holds a free worker's lease request at most this long before answering "no work now,
# ask again"; a worker that hears nothing for much longer knows the broker is gone.
LEASE_HOLD_SECONDS = 1.0

# Leases one request may take, and results it may hand in: a batch of short jobs costs the broker
# one query instead of two per job (bench/broker_capacity.py measures what that lifts).
MAX_BATCH = 32

MAX_MESSAGE_BYTES = 4 * 1024 * 1024  # every message of the bounds below fits; a runaway does not
# Jobs in one Submission: the largest Job's JSON is 6.5 kB (64 names to avoid, every number at
# its longest; tests/schemas/test_wire.py builds it), so any submission of this many fits in
# MAX_MESSAGE_BYTES (the analytic side sends them by the hundred).
MAX_SUBMISSION_JOBS = 500
# Jobs one ConfirmRequest asks about: the reply's largest Accepted is 0.6 kB, so the answer to
# any request fits too.
MAX_CONFIRM_JOBS = 5000
MAX_EPISODE_BYTES = 256 * 1024 * 1024  # a 120 s episode is ~26 MB
# Big bytes (an episode log, up to MAX_EPISODE_BYTES; a model file) move in parts of at most this
# many bytes, each the answer to a query of its own (schemas.parts): so no session anywhere, the
# broker's router included (Zenoh reassembles every message it forwards), need take a message
# larger than a wire message, and a 250 MiB message is dropped on the way by everyone
# (docs/security.md, "Junk on every key"). Half a wire message: a part and its headers fit with
# room to spare; a few in flight keep loopback fast.
PART_BYTES = 2 * 1024 * 1024


class BadMessage(ValueError):
    """A message that cannot be accepted; str() is the one-line reason."""


class WireMessage(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    protocol: Literal[12] = PROTOCOL_VERSION

    @field_validator("protocol", mode="before")
    @classmethod
    def _an_integer(cls, version: object) -> object:
        # Literal[12] would take 12.0 (and JSON true is 1 to Python): a version is an integer.
        if type(version) is not int:
            raise ValueError(_not_an_integer(version))
        return version

    def to_bytes(self) -> bytes:
        return self.model_dump_json().encode()


class Job(BaseModel):
    """One candidate to evaluate: a controller on a trajectory, named by its study."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    job_id: Name
    spec: EpisodeSpec  # the episode to simulate
    avoid: list[Name] = Field(
        [], max_length=64, description="workers that may not run it: a replica runs elsewhere"
    )
    keep_log: bool = Field(
        False,
        description="the study fetches the episode log as soon as the result is confirmed; "
        "either way the worker keeps it, to be fetched in parts (keys.log)",
    )


class Submission(WireMessage):
    """Analytic → broker: queue these jobs for `study` (whose analytic process must be alive)."""

    study: Name
    jobs: list[Job] = Field(max_length=MAX_SUBMISSION_JOBS)


class Rejection(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    job_id: str
    reason: str


class SubmitReply(WireMessage):
    """Broker → analytic: what became of each job of a Submission."""

    study: str
    queued: list[str] = []
    already_pending: list[str] = Field([], description="queued or leased already: a resubmission")
    deferred: list[str] = Field([], description="not queued, the queue is full: submit later")
    rejected: list[Rejection] = []


class JobStatus(StrEnum):
    ok = "ok"  # the episode ran to its end
    diverged = "diverged"  # it ran, and was cut short: still data, penalised by the objectives
    failed = "failed"  # it could not run (e.g. the path is out of reach); `reason` says why
    # The worker lacks a plug-in the job names (a trajectory kind, an objective): `reason` names
    # it. Not the job's outcome but the farm's: the analytic side stops and says so.
    refused = "refused"


class Timings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    simulate_s: float = Field(ge=0, description="reference, then the tick loop")
    encode_s: float = Field(ge=0, description="the MCAP episode log, in memory")


DIGEST_PATTERN = r"^[0-9a-f]{64}$"


# Scores no honest episode can exceed (tests/schemas/test_wire.py scores the extremes). The flange
# is never farther from the shoulder (A2, on A1's axis) than its links' offsets add up to, 0.946 m,
# so it is never 1.9 m from its reference, and a tick not run counts DIVERGED_TICK_ERROR, 1 m.
MAX_TRACKING_ERROR = 2.0  # m: f_acc and max_error
# The applied torque is clipped to its limits, so no tick changes it by more than a swing from
# limit to limit on every joint, 1.13e6 (N·m)², which is what a tick not run counts.
MAX_TORQUE_CHANGE = 1.2e6  # (N·m)²: f_t
MAX_TICKS = round(MAX_DURATION / CONTROL_PERIOD) + 1  # the longest trajectory's
# The applied torque is within ±its limit, so a tick changes it by at most twice the limit, and a
# command less its mean stays within twice the limit: its RMS above any frequency too.
MAX_TORQUE_SHARE = 2.0  # torque_step and chatter


class WireScores(Scores):
    """An episode's scores as a worker reports them: finite numbers within what an episode can
    score, nothing else. Its JSON is Scores' (the fields, in their order, re-bounded)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    f_acc: float = Field(
        ge=0, le=MAX_TRACKING_ERROR, description=Scores.model_fields["f_acc"].description
    )
    f_t: float = Field(
        ge=0, le=MAX_TORQUE_CHANGE, description=Scores.model_fields["f_t"].description
    )
    max_error: float = Field(
        ge=0, le=MAX_TRACKING_ERROR, description=Scores.model_fields["max_error"].description
    )
    saturated_fraction: float = Field(
        ge=0, le=1, description=Scores.model_fields["saturated_fraction"].description
    )
    ticks: int = Field(ge=0, le=MAX_TICKS, description=Scores.model_fields["ticks"].description)
    # Required here: a worker of this protocol measures them (a Scores default is for old pickles).
    torque_step: float = Field(
        ge=0, le=MAX_TORQUE_SHARE, description=Scores.model_fields["torque_step"].description
    )
    speed: float = Field(ge=0, le=SPEED_CAP, description=Scores.model_fields["speed"].description)
    chatter: float = Field(
        ge=0, le=MAX_TORQUE_SHARE, description=Scores.model_fields["chatter"].description
    )
    lag: float = Field(ge=0, le=LAG_CAP, description=Scores.model_fields["lag"].description)
    # A damping ratio is −ln|z| / √(ln²|z| + arg²z): within [−1, 1] for any eigenvalue z.
    damping: float = Field(ge=-1, le=1, description=Scores.model_fields["damping"].description)

    @field_validator(
        "f_acc", "f_t", "max_error", "saturated_fraction", "torque_step", "speed", "chatter", "lag"
    )
    @classmethod
    def _no_negative_zero(cls, value: float) -> float:
        # -0.0 passes ge=0 and would compare equal to 0, but no episode scores it (its sums start
        # at +0.0): refused, so a score's JSON is the one its episode gives.
        if math.copysign(1.0, value) < 0:
            raise ValueError("-0.0 is not a score (no episode makes a negative zero)")
        return value

    @field_validator("damping")
    @classmethod
    def _no_signed_zero(cls, value: float) -> float:
        # As above: worker.stability never gives −0.0 (it adds +0.0), so its JSON is one.
        if value == 0 and math.copysign(1.0, value) < 0:
            raise ValueError("-0.0 is not a score (no episode makes a negative zero)")
        return value


class Result(WireMessage):
    """Worker → broker, then → analytic: how a job went, and the scores the worker computed from
    its log (schemas.objectives.score, the analytic's own code). The worker hands it in to the
    broker first (with its next LeaseRequest: the broker checks that this worker holds this lease
    and keeps what it took), then sends it as the attachment of a sample whose payload is empty:
    the worker keeps the MCAP episode log, to be fetched in parts (keys.log). `digest` and
    `episode_bytes` always describe the log the worker made (both empty when the job failed or
    was refused)."""

    study: Name
    job_id: Name
    lease_id: Name
    worker: Name
    status: JobStatus
    reason: str = Field("", max_length=2000)
    episode_bytes: int = Field(ge=0)
    digest: Annotated[str, Field(pattern=DIGEST_PATTERN)]
    timings: Timings
    scores: WireScores | None = None

    @model_validator(mode="after")
    def _scored_unless_failed(self) -> "Result":
        ran = self.status not in (JobStatus.failed, JobStatus.refused)
        if ran != (self.scores is not None):
            raise ValueError("scores: required for an episode that ran, and only for one")
        return self


class Part(WireMessage):
    """The attachment of a reply to a query for part `part` of big bytes (an episode log, a
    model): their total size. The reply's payload is bytes [part * PART_BYTES, + PART_BYTES) of
    them (schemas.parts checks it, and the fetcher checks the whole's digest)."""

    total: int = Field(ge=0, le=MAX_EPISODE_BYTES)
    part: int = Field(ge=0, le=MAX_EPISODE_BYTES // PART_BYTES)


class Lease(BaseModel):
    """The right to run one job, until `expires_in` seconds from now."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    lease_id: Name  # random: only the worker it was handed to knows it
    study: Name
    job: Job
    expires_in: float = Field(gt=0)


class LeaseRequest(WireMessage):
    """Worker → broker: here are the results of my last batch; give me up to `want` jobs (the
    broker holds a request that hands nothing in while there is no work; `want` 0 only hands in).
    """

    worker: Name
    want: int = Field(1, ge=0, le=MAX_BATCH)
    results: list[Result] = Field([], max_length=MAX_BATCH)

    @model_validator(mode="after")
    def _own_results(self) -> "LeaseRequest":
        for result in self.results:
            if result.worker != self.worker:
                raise ValueError(
                    f"results: a result of worker {result.worker!r} in {self.worker!r}'s request"
                )
        return self


class Verdict(BaseModel):
    """Whether the broker took a handed-in Result as its job's (else: do not send it on)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    job_id: Name
    lease_id: Name
    accepted: bool
    reason: str = Field("", max_length=2000)


class LeaseReply(WireMessage):
    """Broker → worker: a verdict on each result handed in, in order, and leases (none: no work
    now, ask again)."""

    leases: list[Lease] = Field([], max_length=MAX_BATCH)
    verdicts: list[Verdict] = Field([], max_length=MAX_BATCH)


class Accepted(BaseModel):
    """The result the broker took for a job: only the lease holder could hand it in."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    job_id: Name
    lease_id: Name
    worker: Name
    digest: Annotated[str, Field(pattern=DIGEST_PATTERN)]
    scores: WireScores | None = None  # as handed in: what the study counts for the job


class ConfirmRequest(WireMessage):
    """Analytic → broker: which results did you accept for these jobs of my study?"""

    study: Name
    job_ids: list[Name] = Field(max_length=MAX_CONFIRM_JOBS)


class ConfirmReply(WireMessage):
    """Broker → analytic: the accepted result of each job asked about that has one."""

    study: Name
    accepted: list[Accepted] = []


class WorkerState(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    busy: bool
    job: str = Field("", description="study/job_id of its first lease, if busy")
    jobs_done: int


class StudyState(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    queued: int
    leased: int
    done: int


class BrokerStatus(WireMessage):
    """Broker → anyone who asks: the farm at a glance."""

    uptime_s: float
    workers: list[WorkerState]
    studies: list[StudyState]
    jobs_done: int
    jobs_per_s: float = Field(description="completions per second over the last minute")
    requeued: int = Field(description="leases that expired or whose worker died")
    rejected: int = Field(description="bad messages and jobs turned away")
    worker_count: int = Field(0, description="all workers; `workers` lists the first ones")
    busy: int = Field(0, description="workers running a job")
    study_count: int = Field(0, description="all studies; `studies` lists the first ones")
    queued: int = Field(0, description="jobs queued in every study")


MESSAGES: tuple[type[WireMessage], ...] = (
    Submission,
    SubmitReply,
    LeaseRequest,
    LeaseReply,
    Result,
    ConfirmRequest,
    ConfirmReply,
    BrokerStatus,
    Part,
)

M = TypeVar("M", bound=WireMessage)


def describe(
    error: ValidationError, known: Iterable[str] | None = None, noun: str = "field"
) -> str:
    """'field: what is wrong' for the first problem, in plain words ('duration: must be at least
    0.1, got 0'), and how many more there are; a rule about several fields (a model validator's)
    is its message alone. An unknown top-level field is called a `noun` ('unknown limit
    'torque_stp''), followed by the `known` names if given."""
    errors = _one_branch(error.errors())
    first = errors[0]
    more = len(errors) - 1
    suffix = f" (and {more} more problem{'s' if more > 1 else ''})" if more else ""
    loc = first["loc"]
    if not loc and first["type"] == "value_error":
        return f"{first['msg'].removeprefix('Value error, ')}{suffix}"
    if first["type"] == "extra_forbidden" and loc:
        parent = ".".join(str(part) for part in loc[:-1])
        listed = f" (known: {', '.join(known)})" if known is not None and not parent else ""
        said = f"unknown {noun if not parent else 'field'} {str(loc[-1])!r}{listed}"
        return f"{parent}: {said}{suffix}" if parent else f"{said}{suffix}"
    where = ".".join(str(part) for part in loc) or "value"
    return f"{where}: {plainly(first)}{suffix}"


def _one_branch(errors: list[ErrorDetails]) -> list[ErrorDetails]:
    """The errors of a value as one form of a field that takes several (a plant's stiffness:
    numbers or a preset's name) reads it: pydantic reports each form's, its name in the field's
    path ('stiffness.tuple[constrained-float, ...].0'); the first error's form is the one kept,
    and the forms' names leave the path."""
    chosen: dict[tuple, str] = {}
    kept: list[ErrorDetails] = []
    for problem in errors:
        path: list = []
        same = True
        for part in problem["loc"]:
            if isinstance(part, str) and "[" in part:  # a form's name, not a field's
                same = same and chosen.setdefault(tuple(path), part) == part
            else:
                path.append(part)
        if same:
            kept.append({**problem, "loc": tuple(path)})
    return kept


_BOUNDS = {
    "greater_than": ("more than", "gt"),
    "greater_than_equal": ("at least", "ge"),
    "less_than": ("less than", "lt"),
    "less_than_equal": ("at most", "le"),
}


def plainly(problem: ErrorDetails) -> str:
    """One of pydantic's errors as a person says it, without its field: 'must be at least 0.1,
    got 0', 'expected a number, got 'abc'', 'missing', '9 items, at most 7 allowed'."""
    kind, context = problem["type"], problem.get("ctx") or {}
    got = _got(problem.get("input"))
    if kind in _BOUNDS and _BOUNDS[kind][1] in context:
        words, key = _BOUNDS[kind]
        return f"must be {words} {_number(context[key])}{got}"
    if kind in ("float_parsing", "float_type"):
        return f"expected a number{got}"
    if kind in ("int_parsing", "int_type", "int_from_float"):
        return f"expected a whole number{got}"
    if kind == "finite_number":
        return f"must be a finite number{got}"
    if kind == "missing":
        return "missing"
    if kind in ("too_short", "too_long"):
        short = kind == "too_short"
        bound = context.get("min_length" if short else "max_length")
        actual = context.get("actual_length")
        given = f"{actual} item{'' if actual == 1 else 's'}, " if actual is not None else ""
        needs = f"at least {bound} needed" if short else f"at most {bound} allowed"
        return f"{given}{needs}"
    if kind == "value_error":
        return problem["msg"].removeprefix("Value error, ")
    if kind == "string_pattern_mismatch":
        return f"must match the pattern {context.get('pattern', '')}{got}"
    # Any other: pydantic's sentence, without its "Input should be" and its explanations.
    said = problem["msg"].split(", unable to")[0].replace("Input should be", "must be")
    return f"{said}{got}"


def _got(value: object) -> str:
    """', got X' for a value worth quoting (a number, a short text), else nothing."""
    if isinstance(value, bool) or value is None:
        return f", got {'null' if value is None else str(value).lower()}"
    if isinstance(value, int | float):
        return f", got {_number(value)}"
    if isinstance(value, str):
        return f", got {value!r}" if len(value) <= 30 else f", got {value[:30]!r}..."
    return ""


def _number(value: object) -> str:
    """A bound or a value as it would be typed: 0.1, 120, 1200000, 1e+300."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    if isinstance(value, int) and abs(value).bit_length() > 64:
        # Quoted whole, a file's 4,000-digit integer would be the error's whole line.
        return f"an integer of {len(str(abs(value)))} digits"
    return str(value)


def one_line(error: Exception) -> str:
    """What went wrong, in one line: a validation error as `describe` says it (not pydantic's
    several lines with their type codes and links), any other error's text on one line."""
    if isinstance(error, ValidationError):
        return describe(error)
    return " ".join(str(error).split())


def decode(kind: type[M], raw: bytes | None, limit: int = MAX_MESSAGE_BYTES) -> M:
    """Parse `raw` as a `kind` message, or raise BadMessage saying why not.

    Whatever the bytes, BadMessage is the only error that leaves: every listener catches it and
    goes on serving, so anything else a sender can provoke would take the listener down.
    """
    if raw is None:
        raise BadMessage(f"{kind.__name__}: empty message")
    if len(raw) > limit:
        raise BadMessage(f"{kind.__name__}: {len(raw)} bytes, over the limit of {limit}")
    try:
        return _decoded(kind, raw)
    except BadMessage:
        raise
    except RecursionError:  # not expected past pydantic's depth limit; a last line of defence
        raise BadMessage(f"{kind.__name__}: nested too deeply") from None
    except Exception as error:  # e.g. a validator's own TypeError: still the sender's fault
        reason = _one_line(f"{type(error).__name__}: {error}")
        raise BadMessage(f"{kind.__name__}: undecodable ({reason})") from None


def _decoded(kind: type[M], raw: bytes) -> M:
    """decode's work: the fast path for a good message, then the reason a bad one is bad."""
    try:  # the fast path, in one pass of pydantic's own JSON parser
        message = kind.model_validate_json(raw)
        if "protocol" in message.model_fields_set:  # a message must say its version
            return message
    except ValidationError as error:
        first = error.errors(include_url=False, include_context=False, include_input=False)[0]
        if first["type"] == "json_invalid":
            # pydantic's parser is the one that decides what JSON is; json.loads must never see
            # what it refused: json.loads recurses on "[[[[..." until RecursionError.
            if not raw.isascii():
                try:
                    raw.decode()
                except UnicodeDecodeError as bad:
                    where = f"byte {raw[bad.start]:#04x} at {bad.start}"
                    raise BadMessage(f"{kind.__name__}: not JSON (not UTF-8: {where})") from None
            reason = first["msg"].removeprefix("Invalid JSON: ")
            raise BadMessage(f"{kind.__name__}: not JSON ({reason})") from None
    # JSON that pydantic's parser accepted, so within its limits of depth and number size.
    try:
        fields = json.loads(raw)
    except ValueError as error:  # JSONDecodeError, UnicodeDecodeError, too many digits
        raise BadMessage(f"{kind.__name__}: not JSON ({error})") from None
    if not isinstance(fields, dict):
        raise BadMessage(f"{kind.__name__}: not a JSON object")
    version = fields.get("protocol")
    if version is not None and type(version) is not int:
        raise BadMessage(f"{kind.__name__}: {_not_an_integer(version)}")
    if version != PROTOCOL_VERSION:
        raise BadMessage(
            f"{kind.__name__}: protocol version {version!r:.40} is not {PROTOCOL_VERSION}, "
            "the one this gainfarm speaks"
        )
    try:
        return kind.model_validate(fields)
    except ValidationError as error:
        raise BadMessage(f"{kind.__name__}: {_one_line(describe(error))}") from None


def _not_an_integer(version: object) -> str:
    return f"protocol version {version!r:.40} is not an integer ({PROTOCOL_VERSION} is ours)"


def _one_line(reason: str, limit: int = 300) -> str:
    """A reason fit for one log line: it may quote the sender's field names and messages."""
    reason = " ".join(reason.splitlines())
    return reason if len(reason) <= limit else f"{reason[: limit - 3]}..."


class _SubmissionEnvelope(WireMessage):
    study: Name
    jobs: list[object] = Field(max_length=MAX_SUBMISSION_JOBS)


_SubmissionEnvelope.__name__ = "Submission"  # its reasons speak of the message it stands for


def decode_submission(raw: bytes | None) -> tuple[str, list[Job], list[Rejection]]:
    """A Submission, job by job: one bad job is rejected with its reason, the rest still queue.

    BadMessage if the envelope itself (size, JSON, version, study, list of jobs) is bad.
    """
    if raw is not None and len(raw) <= MAX_MESSAGE_BYTES:
        try:  # the usual case, all good, in one pass: it holds the GIL for half as long
            submission = Submission.model_validate_json(raw)
            if "protocol" in submission.model_fields_set:
                return submission.study, list(submission.jobs), []
        except Exception:  # whatever it was, the slow path below says why, as BadMessage
            pass
    envelope = decode(_SubmissionEnvelope, raw)
    jobs: list[Job] = []
    rejected: list[Rejection] = []
    for index, fields in enumerate(envelope.jobs):
        try:
            jobs.append(Job.model_validate(fields))
        except Exception as error:  # a ValidationError, or a validator's own: one bad job
            job_id = fields.get("job_id") if isinstance(fields, dict) else None
            # Named by its id if that is a name: else the reply might quote megabytes of it.
            named = isinstance(job_id, str) and re.fullmatch(NAME_PATTERN, job_id)
            name = job_id if named else f"jobs[{index}]"
            if isinstance(error, ValidationError):
                reason = describe(error)
            else:
                reason = f"undecodable ({type(error).__name__}: {error})"
            rejected.append(Rejection(job_id=name, reason=_one_line(reason)))
    return envelope.study, jobs, rejected
