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

What is refereed: the front, before the run reports it; during the run a share of every
worker's episodes chosen at random (`spot_checked`: a keyed hash of the job id, so the choice is
reproducible on resume and unpredictable to a worker, which never learns the key), at a rate
sized for a stated guarantee (`sized_rate`); and every failure a worker claims (`claims_failure`:
a worker could otherwise sink a good candidate by saying it failed, a claim no score betrays).
The front catches a worker whose lies flatter; spot checks one whose lies never reach the front (a
saboteur, claiming worse than it ran). The cost is those episodes once more, in the analytic's
process (bench/replication_cost.py and docs/performance.md measure it).
"""

import dataclasses
import hashlib
import logging
import math
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import StrEnum

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus, Evaluator
from gainfarm.plugins import PluginError
from gainfarm.schemas.episode import Scores

log = logging.getLogger("gainfarm.analytic")

REFEREE = "-ref"  # the referee's run of a job: the job's id with this
# The spot checks' default guarantee: a worker that lies on LIE_SHARE of the episodes it returns
# is caught with probability at least CONFIDENCE over a run in which it returns its share.
LIE_SHARE = 0.10
CONFIDENCE = 0.99


@dataclass(frozen=True)
class Ran:
    """One episode as it ran: all a run keeps to validate it later. `digest` and `scores` are
    None for an episode that could not run."""

    job_id: str
    worker: str
    digest: str | None
    scores: Scores | None

    @classmethod
    def of(cls, result: EpisodeResult) -> "Ran":
        return cls(result.job_id, result.worker, result.digest, result.scores)


class Check(StrEnum):
    """How an episode was checked: which sample of validation it was in."""

    refereed = "refereed"  # a front member's, before the run reported it
    spot_checked = "spot-checked"  # drawn at random as it returned
    failure_checked = "failure-checked"  # its worker said it failed: run again as it returned
    baseline = "baseline"  # the default gains' on the run's plants (baseline.json)
    held_out = "held-out"  # the held-out check's, before its advice (analytic.tuning.check)


class Ruling(StrEnum):
    """What the referee's run of an episode says of its worker's."""

    agreed = "agreed"  # the same log, bit for bit, and the same scores
    contradicted = "contradicted"  # another log or other scores: the referee's stand
    unsettled = "unsettled"  # the referee could not run it: it fails


# The ledger's count each check adds to (the front's by default).
COUNTS = {
    Check.spot_checked: "spot_checked",
    Check.baseline: "baseline",
    Check.held_out: "held_out",
}


@dataclass
class Ledger:
    """What validation cost and found over a run."""

    refereed: int = 0  # front episodes the referee ran again
    spot_checked: int = 0  # episodes drawn at random as they returned, run again
    disagreements: int = 0  # a worker's log or scores were not the referee's
    unsettled: int = 0  # episodes the referee could not run: failed, never reported
    failures_checked: int = 0  # failures workers claimed, run again
    baseline: int = 0  # the default gains' episodes (baseline.json), run again
    held_out: int = 0  # the held-out check's episodes, run again before its advice
    # The workers the referee contradicted, each with the evidence: the first job it lied about.
    dissenters: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0

    def __setstate__(self, state: dict) -> None:
        before = {"spot_checked": 0, "failures_checked": 0, "baseline": 0, "held_out": 0}
        self.__dict__.update({**before, **state})


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


def sized_rate(episodes: float, share: float = LIE_SHARE, confidence: float = CONFIDENCE) -> float:
    """The spot checks' rate r at which a worker lying on a `share` of its `episodes` is caught
    with probability at least `confidence`:

        r = 1 - (1 - confidence) ** (1 / (share * episodes)), at most 1

    since each of its share * episodes lies is drawn independently with probability r (a keyed
    hash), and all of them are missed with probability (1 - r) ** (share * episodes). With no
    episodes to speak of, every one is checked (1)."""
    lies = share * episodes
    if lies <= 0:
        return 1.0
    return min(1.0, 1.0 - (1.0 - confidence) ** (1.0 / lies))


def caught_probability(rate: float, episodes: float, share: float = LIE_SHARE) -> float:
    """The chance that spot checks at `rate` catch a worker lying on a `share` of its
    `episodes` (sized_rate's inverse): 1 - (1 - rate) ** (share * episodes)."""
    if rate >= 1.0:
        return 1.0 if share * episodes > 0 else 0.0
    return -math.expm1(share * episodes * math.log1p(-rate))


def claims_failure(result: EpisodeResult) -> bool:
    """Whether `evaluation` is a worker's word that the episode failed (not this process's
    verdict on a result it could not use, which names no worker): the referee runs it too."""
    return result.status == EpisodeStatus.failed and bool(result.worker)


def validate(
    evaluator: Evaluator,
    originals: Iterable[EpisodeResult],
    ledger: Ledger,
    *,
    referee: Evaluator,
    check: Check = Check.refereed,
) -> Validation:
    """Run each original (an evaluation that ran: ok or diverged; or a failure its worker
    claims) again on `referee`; a worker whose log or scores differ from the referee's, or who
    said an episode failed that the referee runs to scores, is distrusted on `evaluator`. A
    failure the referee's run fails too stands (agreed). `check` says which count of the ledger
    the episodes go to."""
    started = time.monotonic()
    standing = {
        original.job_id: original
        for original in originals
        if original.digest or claims_failure(original)
    }
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
        if not _ran(standing[job_id]) and rerun is not None:  # a failure its worker claims
            ledger.failures_checked += 1
            validation.rulings[job_id] = _settle_failure(job_id, rerun, standing, ledger, evaluator)
            continue
        if not _ran(standing[job_id]):  # the referee cannot run it either: the failure stands
            log.error("failed episode %s could not be refereed: its failure stands", job_id)
            ledger.unsettled += 1
            validation.rulings[job_id] = Ruling.unsettled
            continue
        if rerun is None or not _ran(rerun):
            why = rerun.reason if rerun is not None else "no result"
            log.error("episode %s could not be refereed (%s): it fails", job_id, why)
            validation.unsettled.add(job_id)
            validation.rulings[job_id] = Ruling.unsettled
            del standing[job_id]
            continue
        name = COUNTS.get(check, "refereed")
        setattr(ledger, name, getattr(ledger, name) + 1)
        validation.rulings[job_id] = _settle(job_id, rerun, standing, ledger, evaluator)
    ledger.unsettled += len(validation.unsettled)
    ledger.seconds += time.monotonic() - started
    return validation


def _ran(result: EpisodeResult) -> bool:
    return result.digest is not None


def _settle_failure(
    job_id: str,
    rerun: EpisodeResult,
    standing: dict[str, EpisodeResult],
    ledger: Ledger,
    evaluator: Evaluator,
) -> Ruling:
    """A failure a worker claimed, against the referee's run of it: an honest failure if that
    fails too; else the worker lied (a good candidate sunk by a claim no score betrays)."""
    if not _ran(rerun):
        return Ruling.agreed
    evidence = f"failed job {job_id} that the referee ran to scores"
    return _contradicted(job_id, rerun, standing, ledger, evaluator, evidence)


def _distrust(worker: str, evidence: str, ledger: Ledger) -> None:
    """Name `worker` with the evidence (the first), and say so."""
    if worker in ledger.dissenters:
        return
    ledger.dissenters[worker] = evidence
    log.error(
        "worker %r %s: its results are distrusted and it gets no more of this run's jobs",
        worker,
        evidence,
    )


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
    what = "a log" if original.digest != rerun.digest else "scores its log does not have"
    evidence = f"returned {what} for {job_id} that the referee's run contradicts"
    return _contradicted(job_id, rerun, standing, ledger, evaluator, evidence)


def _contradicted(
    job_id: str,
    rerun: EpisodeResult,
    standing: dict[str, EpisodeResult],
    ledger: Ledger,
    evaluator: Evaluator,
    evidence: str,
) -> Ruling:
    """The referee's run stands in for the original, whose worker is named with `evidence` and
    distrusted."""
    original = standing[job_id]
    ledger.disagreements += 1
    _distrust(original.worker, evidence, ledger)
    evaluator.distrust(original.worker)
    kept = rerun.log
    if kept is not None:  # the referee's log where the original's is, or would be, kept
        kept = kept.replace(original.log or kept.with_name(f"{job_id}.mcap"))
    standing[job_id] = dataclasses.replace(rerun, job_id=job_id, log=kept)
    return Ruling.contradicted
