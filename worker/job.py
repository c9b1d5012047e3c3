"""One job, start to finish: simulate it, score and encode its log, say how it went. No Zenoh.

The scores are the analytic side's own (schemas.objectives.score), computed on the episode as
simulated; they equal the scores of the log decoded from its MCAP bytes exactly (test_job.py).

A job that cannot run is a result too (status failed, with the reason), never an exception that
would take the worker down: the farm goes on serving, and the analytic side learns why. A job
that names a plug-in this worker lacks (a trajectory kind, an objective: gainfarm.plugins) is
refused, the reason naming the plug-in, before anything is simulated.
"""

import hashlib
import time
from collections.abc import Callable
from dataclasses import dataclass

from gainfarm import plugins
from gainfarm.models.dynamics import DynamicsModel
from gainfarm.models.urdf import description
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.mcap_episode import episode_bytes
from gainfarm.schemas.objectives import Objective, score
from gainfarm.schemas.wire import JobStatus, Lease, Result, Timings, WireScores
from gainfarm.worker.episode import run_episode
from gainfarm.worker.feedforward import ModelUnavailable
from gainfarm.worker.ik import UnreachablePath
from gainfarm.worker.reference import InfeasibleReference

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
    started = time.perf_counter()
    content = b""
    reason = ""
    scores = None
    try:
        objectives = plugins_of(spec)
    except plugins.PluginError as error:
        took = time.perf_counter() - started
        return Outcome(JobStatus.refused, str(error), b"", Timings(simulate_s=took, encode_s=0.0))
    try:
        feedforward = None
        if spec.feedforward is not None:
            if model is None:
                raise ModelUnavailable(
                    f"feed-forward model {spec.feedforward[:12]}: this worker cannot fetch models"
                )
            feedforward = model(spec.feedforward)
        log = run_episode(spec, feedforward)
    except (UnreachablePath, InfeasibleReference, ModelUnavailable) as error:
        status, reason = JobStatus.failed, str(error)
    except Exception as error:  # a bug or a bad spec must not kill a cobot serving a farm
        status, reason = JobStatus.failed, f"{type(error).__name__}: {error}"
    else:
        status = JobStatus.diverged if log.metadata.diverged else JobStatus.ok
        reason = log.metadata.divergence
    simulated = time.perf_counter()
    if status != JobStatus.failed:
        try:  # scores the wire cannot carry (not finite) would be a bug: the job fails, not all
            content = episode_bytes(log, description())
            scores = score(log, objectives)
            WireScores(**scores.model_dump())
        except Exception as error:  # a plug-in objective's too: a stranger's code
            status, content, scores = JobStatus.failed, b"", None
            reason = " ".join(f"its log: {type(error).__name__}: {error}".split())
    encoded = time.perf_counter()
    timings = Timings(simulate_s=simulated - started, encode_s=encoded - simulated)
    return Outcome(status, reason, content, timings, scores)


def plugins_of(spec: EpisodeSpec) -> dict[str, Objective]:
    """The plug-in objectives the spec names, by name, once its trajectory kind is known to be
    here too. PluginError, naming the first plug-in this process lacks or cannot load."""
    plugins.load(plugins.TRAJECTORIES, spec.trajectory.kind)
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
    outcome = run(lease.job.spec, model)
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
