"""Validation by a referee: before the run reports its front, the analytic runs every front
member's episodes itself, and each worker's log must agree with its own bit for bit, and the
worker's scores with the log's.

Episodes are deterministic (same spec, same software: the same bytes), so a worker that returns a
log it did not honestly simulate, one altered by a single torque sample, or scores its log does
not have, disagrees with the referee. Volunteer-computing farms validate by a vote among workers
instead; a vote can be won by colluding workers (on the plain profile one process can register
two names), and waited out on a farm with nobody left to vote. The referee is an evaluator the
analytic trusts: its own process (analytic.evaluators.inprocess). Whoever disagrees with it is
named, and the evaluator stops giving it this run's jobs; the member takes the referee's log and
scores. An episode the referee cannot run (a plug-in missing here) is left unsettled, and the
caller must not report it.

Two samples are refereed: the front, before the run reports it, and during the run a share of
every worker's episodes chosen at random (`spot_checked`: a keyed hash of the job id, so the
choice is reproducible on resume and unpredictable to a worker, which never learns the key). The
front catches a worker whose lies flatter; spot checks one whose lies never reach the front (a
saboteur, claiming worse than it ran): at rate r a worker lying on a share p of its episodes is
caught within n of them with probability 1 - (1 - r p)^n. The cost is those episodes once more,
in the analytic's process (bench/replication_cost.py and docs/performance.md measure it).
"""

import dataclasses
import hashlib
import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import StrEnum

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Evaluator
from gainfarm.plugins import PluginError
from gainfarm.schemas.episode import Scores

log = logging.getLogger("gainfarm.analytic")

REFEREE = "-ref"  # the referee's run of a job: the job's id with this


@dataclass(frozen=True)
class Ran:
    """One episode as it ran: all a run keeps to validate it later. `digest` and `scores` are
    None for an episode that could not run."""

    job_id: str
    worker: str
    digest: str | None
    scores: Scores | None

    @classmethod
    def of(cls, evaluation: EpisodeResult) -> "Ran":
        return cls(evaluation.job_id, evaluation.worker, evaluation.digest, evaluation.scores)


class Check(StrEnum):
    """How an episode was checked: which sample of validation it was in."""

    refereed = "refereed"  # a front member's, before the run reported it
    spot_checked = "spot-checked"  # drawn at random as it returned


class Ruling(StrEnum):
    """What the referee's run of an episode says of its worker's."""

    agreed = "agreed"  # the same log, bit for bit, and the same scores
    contradicted = "contradicted"  # another log or other scores: the referee's stand
    unsettled = "unsettled"  # the referee could not run it: it fails


@dataclass
class Ledger:
    """What validation cost and found over a run."""

    refereed: int = 0  # front episodes the referee ran again
    spot_checked: int = 0  # episodes drawn at random as they returned, run again
    disagreements: int = 0  # a worker's log or scores were not the referee's
    unsettled: int = 0  # episodes the referee could not run: failed, never reported
    # The workers the referee contradicted, each with the evidence: the first job it lied about.
    dissenters: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update({"spot_checked": 0, **state})


@dataclass
class Validation:
    """The outcome of validating some evaluations: each job's standing evaluation (the original,
    or the referee's where they disagree), the jobs left unsettled (not in `standing`: never
    to be reported as validated) and the referee's ruling on each job."""

    standing: dict[str, EpisodeResult]
    unsettled: set[str] = field(default_factory=set)
    rulings: dict[str, Ruling] = field(default_factory=dict)


def spot_checked(key: bytes, job_id: str, rate: float) -> bool:
    """Whether the episode `job_id` is drawn for a spot check, at `rate`: a keyed hash, so a
    worker that does not know `key` cannot tell which of its episodes will be checked."""
    draw = int.from_bytes(hashlib.sha256(key + job_id.encode()).digest()[:8], "big")
    return draw < rate * 2**64


def validate(
    evaluator: Evaluator,
    originals: Iterable[EpisodeResult],
    ledger: Ledger,
    *,
    referee: Evaluator,
    check: Check = Check.refereed,
) -> Validation:
    """Run each original (an evaluation that ran: ok or diverged) again on `referee`; a worker
    whose log or scores differ from the referee's is distrusted on `evaluator`. `check` says
    which count of the ledger the episodes go to."""
    started = time.monotonic()
    standing = {original.job_id: original for original in originals if original.digest}
    jobs = {f"{job_id}{REFEREE}": original.spec for job_id, original in standing.items()}
    referee.submit(jobs)
    reruns = {}
    try:
        for rerun in referee.results():
            reruns[rerun.job_id.removesuffix(REFEREE)] = rerun
    except PluginError as error:  # this process lacks a plug-in the episode needs
        log.error("the referee cannot run every front member's episode: %s", error)
    finally:  # stopped (Ctrl-C) or failed: leave nothing queued in the referee
        referee.cancel(jobs)
    validation = Validation(standing)
    for job_id in list(standing):
        rerun = reruns.get(job_id)
        if rerun is None or not _ran(rerun):
            why = rerun.reason if rerun is not None else "no result"
            log.error("episode %s could not be refereed (%s): it fails", job_id, why)
            validation.unsettled.add(job_id)
            validation.rulings[job_id] = Ruling.unsettled
            del standing[job_id]
            continue
        if check == Check.spot_checked:
            ledger.spot_checked += 1
        else:
            ledger.refereed += 1
        validation.rulings[job_id] = _settle(job_id, rerun, standing, ledger, evaluator)
    ledger.unsettled += len(validation.unsettled)
    ledger.seconds += time.monotonic() - started
    return validation


def _ran(evaluation: EpisodeResult) -> bool:
    return evaluation.digest is not None


def _settle(
    job_id: str,
    rerun: EpisodeResult,
    standing: dict[str, EpisodeResult],
    ledger: Ledger,
    evaluator: Evaluator,
) -> Ruling:
    original = standing[job_id]
    if original.digest == rerun.digest and original.scores == rerun.scores:
        if rerun.log is not None and original.log is None:  # the same bytes: no fetch needed
            here = rerun.log.replace(rerun.log.with_name(f"{job_id}.mcap"))
            standing[job_id] = dataclasses.replace(original, log=here)
        elif rerun.log is not None:
            rerun.log.unlink(missing_ok=True)
        return Ruling.agreed
    ledger.disagreements += 1
    what = "a log" if original.digest != rerun.digest else "scores its log does not have"
    if original.worker not in ledger.dissenters:
        ledger.dissenters[original.worker] = (
            f"returned {what} for {job_id} that the referee's run contradicts"
        )
        evaluator.distrust(original.worker)
        log.error(
            "worker %r returned %s for %s, which the referee's own run of it contradicts: its "
            "results are distrusted and it gets no more of this run's jobs",
            original.worker,
            what,
            job_id,
        )
    kept = rerun.log
    if kept is not None:  # the referee's log where the original's is, or would be, kept
        kept = kept.replace(original.log or kept.with_name(f"{job_id}.mcap"))
    standing[job_id] = dataclasses.replace(rerun, job_id=job_id, log=kept)
    return Ruling.contradicted
