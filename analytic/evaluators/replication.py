"""Validation by replication: before a candidate enters the front, another worker runs its
episodes again, and the two logs must agree bit for bit.

Episodes are deterministic (same spec, same software: the same bytes), so a worker that returns a
log it did not honestly simulate, or one altered by a single torque sample, disagrees with an
honest replica. Volunteer-computing farms validate the same way. A disagreement is settled by a
third worker, avoiding both: the log two of three agree on stands, the worker that dissented is
named, and the evaluator stops giving it this run's jobs. Only candidates about to enter the front
are replicated, so the cost is a few per cent of the evaluations (bench/soak.py and
docs/performance.md measure it); a farm of one worker has nobody to replicate on, and does not.
"""

import dataclasses
import logging
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Evaluator
from gainfarm.schemas.episode import Scores

log = logging.getLogger("gainfarm.analytic")

REPLICA = "-r"  # a replica's job id is the original's with this and the replica's number
# A replica must run on another worker than its original; if no other worker takes any replica
# for this long (the others left), validation gives up on those left rather than hang the run.
PATIENCE_SECONDS = 120.0
CHECK_SECONDS = 5.0  # how often a wait for replicas looks at the clock


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


@dataclass
class Ledger:
    """What replication cost and found over a run."""

    replicated: int = 0  # episodes run again
    extra_evaluations: int = 0  # replicas and tie-breaks
    disagreements: int = 0
    undecided: int = 0  # no majority, or no other worker to replicate on
    dissenters: set[str] = field(default_factory=set)
    seconds: float = 0.0


@dataclass
class Validation:
    """The outcome of validating some evaluations: each job's standing evaluation (an original
    or, where it lost a vote, the majority's), and evaluations of other jobs that arrived while
    waiting for the replicas (to be handled by the caller as usual)."""

    standing: dict[str, EpisodeResult]
    others: list[EpisodeResult]


def validate(
    evaluator: Evaluator,
    originals: Iterable[EpisodeResult],
    ledger: Ledger,
    patience: float = PATIENCE_SECONDS,
) -> Validation:
    """Replicate each original (an evaluation that ran: ok or diverged) on another worker;
    settle disagreements by a third. Blocks until every replica is in, or until none has come
    for `patience` s (the other workers left, say): those left out stay undecided."""
    started = time.monotonic()
    standing = {original.job_id: original for original in originals if original.digest}
    others: list[EpisodeResult] = []
    votes: dict[str, list[EpisodeResult]] = {job_id: [e] for job_id, e in standing.items()}
    round_ = 1
    undecided = set(standing)
    while undecided:
        replicas = {f"{job_id}{REPLICA}{round_}": job_id for job_id in undecided}
        evaluator.submit(
            {replica: standing[job_id].spec for replica, job_id in replicas.items()},
            avoid={replica: [e.worker for e in votes[job]] for replica, job in replicas.items()},
        )
        ledger.extra_evaluations += len(replicas)
        if round_ == 1:
            ledger.replicated += len(replicas)
        try:
            for evaluation in _until_done(evaluator, set(replicas), others, patience):
                votes[replicas[evaluation.job_id]].append(evaluation)
        finally:  # stopped while waiting (Ctrl-C): leave no replica queued in the evaluator
            evaluator.cancel(replicas)
        undecided = set()
        for job_id in replicas.values():
            verdict = _count(votes[job_id])
            replicated = len(votes[job_id]) == 2 and _ran(votes[job_id][1])
            if verdict is None and round_ == 1 and replicated:
                undecided.add(job_id)  # two disagree: a third decides
                ledger.disagreements += 1
                continue
            _settle(job_id, votes[job_id], verdict, standing, ledger, evaluator)
        round_ += 1
    ledger.seconds += time.monotonic() - started
    return Validation(standing, others)


def _until_done(
    evaluator: Evaluator, replicas: set[str], others: list[EpisodeResult], patience: float
) -> Iterator[EpisodeResult]:
    """The replicas' evaluations as they come (others' go to `others`), until all are in or
    none has come for `patience` s."""
    waiting = set(replicas)
    heard = time.monotonic()
    while waiting and time.monotonic() - heard < patience:
        for evaluation in evaluator.results(timeout=min(patience, CHECK_SECONDS)):
            if evaluation.job_id not in waiting:
                others.append(evaluation)
                continue
            waiting.discard(evaluation.job_id)
            heard = time.monotonic()
            yield evaluation
            if not waiting:
                return
    if waiting:
        log.warning("%d replicas found no worker in %.0f s: left undecided", len(waiting), patience)


def _ran(evaluation: EpisodeResult) -> bool:
    return evaluation.digest is not None


def _count(votes: list[EpisodeResult]) -> str | None:
    """The digest a majority of the votes that ran agree on (two of two, two of three)."""
    digests = [vote.digest for vote in votes if _ran(vote)]
    for digest in digests:
        if digests.count(digest) >= 2:
            return digest
    return None


def _settle(
    job_id: str,
    votes: list[EpisodeResult],
    majority: str | None,
    standing: dict[str, EpisodeResult],
    ledger: Ledger,
    evaluator: Evaluator,
) -> None:
    if majority is None:
        ledger.undecided += 1
        why = "no other worker ran it" if len(votes) < 2 or not _ran(votes[1]) else "no majority"
        log.warning("episode %s could not be validated: %s", job_id, why)
        return
    for vote in votes:
        if _ran(vote) and vote.digest != majority and vote.worker not in ledger.dissenters:
            ledger.dissenters.add(vote.worker)
            evaluator.distrust(vote.worker)
            log.error(
                "worker %r returned a log for %s that %d other workers contradict: its results "
                "are distrusted and it gets no more of this run's jobs",
                vote.worker,
                job_id,
                sum(1 for other in votes if other.digest == majority),
            )
    original = standing[job_id]
    if original.digest != majority:
        winner = next(vote for vote in votes if vote.digest == majority)
        if winner.log is not None and original.log is not None:
            winner.log.replace(original.log)  # the majority's log, where the run keeps logs
        standing[job_id] = dataclasses.replace(winner, job_id=job_id, log=original.log)
    for vote in votes[1:]:  # replicas, once counted, are not kept
        if vote.log is not None:
            vote.log.unlink(missing_ok=True)
