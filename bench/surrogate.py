"""Simulated cobots for whole experiments: the real worker code (batches, hand-ins, logs kept and
served) around a stand-in for the physics, so that an experiment's wall time measures the farm and
the analytic side, not the episodes.

An episode's "log" is its spec as JSON: deterministic, so replicas agree bit for bit and a log
fetched or simulated again is the same bytes. Its scores are the tuning loop's toy objective
(tests/analytic/toy.py: a smooth trade-off between accuracy and torque steps, so NSGA-II finds a
real front and the convergence rule stops a run). A job takes `job_seconds` per 5 s of episode.
"""

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gainfarm.edges.files import write_atomically
from gainfarm.models.dynamics import DynamicsModel
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog
from gainfarm.schemas.wire import JobStatus, Timings
from gainfarm.worker.job import Outcome, Simulate

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository, for tests/
from tests.analytic.toy import toy_scores

EPISODE_SECONDS = 5.0  # the paper's trajectory duration: a job of this length takes job_seconds


def surrogate(job_seconds: float, busy: Any = None) -> Simulate:
    """A stand-in for worker.job.simulate whose episodes take `job_seconds` per 5 s; each
    episode's time is added to `busy` (a multiprocessing Value of doubles), if given."""

    def run(spec: EpisodeSpec, _model: Callable[[str], DynamicsModel] | None) -> Outcome:
        started = time.perf_counter()
        time.sleep(job_seconds * spec.trajectory.duration / EPISODE_SECONDS)
        content = spec.model_dump_json().encode()
        took = time.perf_counter() - started
        if busy is not None:
            with busy.get_lock():
                busy.value += took
        timings = Timings(simulate_s=took, encode_s=0.0)
        return Outcome(JobStatus.ok, "", content, timings, toy_scores(spec))

    return run


def read_surrogate_log(content: bytes, spec: EpisodeSpec, path: Path | None, source: str) -> Scores:
    """analytic.evaluator.accept_log for a surrogate's logs: check, keep and score one."""
    try:
        logged = EpisodeSpec.model_validate_json(content)
    except ValueError:
        raise NotAnEpisodeLog(f"{source}: not a surrogate episode's log") from None
    if logged != spec:
        raise NotAnEpisodeLog("the log is of another episode than the one submitted")
    if path is not None:
        write_atomically(path, content)
    return toy_scores(spec)
