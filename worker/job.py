"""One job, start to finish: simulate it, score and encode its log, say how it went. No Zenoh.

The scores are the analytic side's own (schemas.objectives.score), computed on the episode as
simulated; they equal the scores of the log decoded from its MCAP bytes exactly (test_job.py).

A job that cannot run is a result too (status failed, with the reason), never an exception that
would take the worker down: the farm goes on serving, and the analytic side learns why. A job
that names a plug-in this worker lacks (a robot, a trajectory kind, an objective:
gainfarm.plugins), a plant its robot cannot be (models.PlantError: a per-joint number of another
joint count, an inertial set it lacks, a payload past its rating) or gains without one pair per
joint of its robot is refused, the reason saying which, before anything is simulated.
"""

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from gainfarm import plugins
from gainfarm.models import PlantError, resolve, robot_of
from gainfarm.models.dynamics import DynamicsModel, WrongRobot, check_robot
from gainfarm.models.urdf import description
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.episode_log import EpisodeLog, RobotDescription
from gainfarm.schemas.mcap_episode import episode_bytes
from gainfarm.schemas.objectives import Objective, score
from gainfarm.schemas.wire import JobStatus, Lease, Result, Timings, WireScores
from gainfarm.worker.episode import Prepared, compensation, simulate_all
from gainfarm.worker.feedforward import ModelUnavailable
from gainfarm.worker.ik import UnreachablePath
from gainfarm.worker.reference import InfeasibleReference, reference_for
from gainfarm.worker.trajectories import kind_of

REASON_LIMIT = 2000  # characters: Result.reason's bound


@dataclass(frozen=True)
class Outcome:
    """How an episode went, its MCAP log and its scores (empty and None if it could not run)."""

    status: JobStatus
    reason: str
    content: bytes
    timings: Timings
    scores: Scores | None = None

    @property
    def digest(self) -> str:
        """The log's SHA-256: what the farm checks a log by, and replicas compare."""
        return hashlib.sha256(self.content).hexdigest()


def simulate(spec: EpisodeSpec, model: Callable[[str], DynamicsModel] | None = None) -> Outcome:
    """Run the episode, encode its log and score it; never raises for a spec that cannot run.
    `model` gives the feed-forward model of a digest, if the spec names one (ModelUnavailable if
    it cannot)."""
    return simulate_batch([spec], model)[0]


ModelOf = Callable[[str], DynamicsModel]  # a feed-forward model by its digest


def simulate_batch(
    specs: Sequence[EpisodeSpec],
    model: ModelOf | Sequence[ModelOf | None] | None = None,
    threads: int = 1,
) -> list[Outcome]:
    """`simulate` every spec, their episodes stepped together on `threads` threads; each
    outcome is the one its spec has alone, log byte for byte (worker.stepping). `model`: as
    `simulate`'s, or one per spec. An episode's timings are its share of the batch's set-up and
    stepping, then its own encoding and scoring."""
    if not specs:
        return []
    models = model if isinstance(model, Sequence) else [model] * len(specs)
    started = time.perf_counter()
    prepared: dict[int, Prepared] = {}
    outcomes: dict[int, Outcome] = {}
    for index, spec in enumerate(specs):
        began = time.perf_counter()
        refusal = refused(spec)
        if refusal is not None:
            took = Timings(simulate_s=time.perf_counter() - began, encode_s=0.0)
            outcomes[index] = Outcome(JobStatus.refused, refusal, b"", took)
            continue
        try:
            reference = reference_for(spec.trajectory, spec.plant.robot)
            learned = _model(spec, models[index])
            prepared[index] = (spec, reference, compensation(spec, reference, learned))
        except Exception as error:
            outcomes[index] = _failed(error, time.perf_counter() - began)
    ran = _episodes(list(prepared.values()), threads)
    # Encoding overlapped the stepping: an episode's share of the batch is the whole less its
    # own encoding, which its timings give apart.
    encoding = sum(outcome.timings.encode_s for outcome in ran)
    share = max(0.0, time.perf_counter() - started - encoding) / len(specs)
    for index, outcome in zip(prepared, ran, strict=True):
        timings = outcome.timings.model_copy(update={"simulate_s": share})
        outcomes[index] = replace(outcome, timings=timings)
    return [outcomes[index] for index in range(len(specs))]


def refused(spec: EpisodeSpec) -> str | None:
    """Why this worker refuses the job, in one line, or None: a plug-in it lacks (its robot
    first), a plant its robot cannot be, gains not one pair per joint of its robot."""
    try:
        objectives_of(spec)
        resolve(spec.plant)
    except (plugins.PluginError, PlantError) as error:
        return str(error)
    robot = robot_of(spec.plant)
    joints, pairs = len(robot.joint_names), len(spec.gains.kp)
    if pairs != joints:
        return (
            f"gains: {pairs} Kp/Kd pairs for {robot.name}'s {joints} joints "
            f"({', '.join(robot.joint_names)})"
        )
    return None


def drawing(robot: str) -> RobotDescription:
    """What draws the arm in its log for ROS tools (/robot_description and /tf): its URDF and
    frames, from its own model (models/urdf.py)."""
    return description(robot)


def _model(spec: EpisodeSpec, model: Callable[[str], DynamicsModel] | None) -> DynamicsModel | None:
    if spec.feedforward is None:
        return None
    if model is None:
        raise ModelUnavailable(
            f"feed-forward model {spec.feedforward[:12]}: this worker cannot fetch models"
        )
    try:  # a model of another arm, even of as many joints, computes torques for other links
        return check_robot(model(spec.feedforward), spec.plant)
    except WrongRobot as error:
        raise ModelUnavailable(f"feed-forward model {spec.feedforward[:12]}: {error}") from None


def _episodes(prepared: list[Prepared], threads: int) -> list[Outcome]:
    """The episodes' outcomes, stepped together, each encoded and scored on the thread that
    stepped it; if that fails (a bug, or a spec no check caught), each alone, so that only the
    episode at fault fails."""
    try:
        return simulate_all(prepared, threads, _outcome)
    except Exception as error:
        if len(prepared) == 1:
            return [_failed(error, 0.0)]
        return [_episodes([episode], 1)[0] for episode in prepared]


def _failed(error: Exception, took: float) -> Outcome:
    if isinstance(error, UnreachablePath | InfeasibleReference | ModelUnavailable):
        reason = str(error)
    else:  # a bug or a bad spec must not kill a cobot serving a farm
        reason = f"{type(error).__name__}: {error}"
    return Outcome(JobStatus.failed, reason, b"", Timings(simulate_s=took, encode_s=0.0))


def _outcome(log: EpisodeLog, simulate_s: float = 0.0) -> Outcome:
    """Encode and score an episode that ran; a log the wire cannot carry fails its job."""
    status = JobStatus.diverged if log.metadata.diverged else JobStatus.ok
    reason = log.metadata.divergence
    began = time.perf_counter()
    try:  # scores the wire cannot carry (not finite) would be a bug: the job fails, not all
        content = episode_bytes(log, drawing(log.metadata.spec.plant.robot))
        scores: Scores | None = score(log, objectives_of(log.metadata.spec))
        WireScores(**scores.model_dump())
    except Exception as error:  # a plug-in objective's too: a stranger's code
        status, content, scores = JobStatus.failed, b"", None
        reason = " ".join(f"its log: {type(error).__name__}: {error}".split())
    timings = Timings(simulate_s=simulate_s, encode_s=time.perf_counter() - began)
    return Outcome(status, reason, content, timings, scores)


def objectives_of(spec: EpisodeSpec) -> dict[str, Objective]:
    """The plug-in objectives the spec names, by name, once its robot and trajectory kind are
    known to be here too. PluginError, naming the first plug-in this process lacks or cannot
    load."""
    robot_of(spec.plant)
    kind_of(spec.trajectory)  # a kind that cannot be had, or is of no form the worker takes
    return plugins.load_plugins(plugins.OBJECTIVES, spec.objectives)


# What runs an episode: simulate, or a stand-in (bench/campaign.py --simulated).
Simulate = Callable[[EpisodeSpec, Callable[[str], DynamicsModel] | None], Outcome]


def execute(
    lease: Lease,
    worker: str,
    model: Callable[[str], DynamicsModel] | None = None,
    run: Simulate = simulate,
) -> tuple[Result, bytes]:
    """Run the lease's episode; return its Result, with its scores, and the MCAP bytes (empty if
    it failed)."""
    return _result(lease, worker, run(lease.job.spec, model))


def _result(lease: Lease, worker: str, outcome: Outcome) -> tuple[Result, bytes]:
    result = Result(
        study=lease.study,
        job_id=lease.job.job_id,
        lease_id=lease.lease_id,
        worker=worker,
        status=outcome.status,
        reason=outcome.reason[:REASON_LIMIT],
        episode_bytes=len(outcome.content),
        digest=outcome.digest,
        timings=outcome.timings,
        scores=None if outcome.scores is None else WireScores(**outcome.scores.model_dump()),
    )
    return result, outcome.content


def execute_batch(
    leases: Sequence[Lease],
    worker: str,
    model_of: Callable[[Lease], ModelOf] | None = None,
    threads: int = 1,
) -> list[tuple[Result, bytes]]:
    """`execute` every lease, their episodes stepped together on `threads` threads.
    `model_of(lease)` gives the lease's feed-forward models (fetched from its study)."""
    models = [None if model_of is None else model_of(lease) for lease in leases]
    specs = [lease.job.spec for lease in leases]
    outcomes = simulate_batch(specs, models, threads)
    return [_result(lease, worker, out) for lease, out in zip(leases, outcomes, strict=True)]
