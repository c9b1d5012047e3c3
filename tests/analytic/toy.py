"""A toy objective for the tuning loop's fast tests: a smooth function of the gains that trades
accuracy against torque steps as the real episodes do (stiffer gains: smaller error, larger
torque steps), so NSGA-II has a real front to find, in microseconds per candidate."""

import numpy as np

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus
from gainfarm.schemas import EpisodeSpec, Scores
from gainfarm.schemas.gains import DEFAULT_GAINS


def toy_scores(spec: EpisodeSpec) -> Scores:
    """Stiffer: more accurate and rougher; more damping: rougher still, a little more accurate."""
    kp = np.array(spec.gains.kp) / np.array(DEFAULT_GAINS.kp)
    kd = np.array(spec.gains.kd) / np.array(DEFAULT_GAINS.kd)
    f_acc = float(np.mean(0.01 / kp + 0.002 / kd))
    f_t = float(np.mean(kp**2 + 0.5 * kd))
    return Scores(
        f_acc=f_acc,
        f_t=f_t,
        max_error=2 * f_acc,
        saturated_fraction=0.0,
        diverged=False,
        ticks=1,
        damping=0.1,  # a stable loop, as a worker's scores claim one (worker.stability)
    )


def claimed_failure(job_id: str, spec: EpisodeSpec, worker: str = "w1") -> EpisodeResult:
    """A worker's word that the episode failed (the referee runs it too)."""
    return EpisodeResult(
        job_id=job_id,
        spec=spec,
        status=EpisodeStatus.failed,
        scores=None,
        log=None,
        reason="it could not run",
        worker=worker,
        attempts=1,
        timings=None,
    )
