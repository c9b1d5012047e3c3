"""The seam between a tuning run and whatever simulates its episodes.

A run hands an evaluator episode specs under job ids and takes back one `EpisodeResult` per job,
in whatever order they complete; it never learns whether they ran on a farm of a hundred cobots
(`analytic.farm.FarmClient`) or one after another in this process
(`analytic.inprocess.InProcessEvaluator`). pymoo's runner and Optuna's injectable storage play
the same part: the loop is written once, and tested in milliseconds with a stand-in.
"""

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Protocol

from gainfarm.edges.files import write_atomically
from gainfarm.models import written_out
from gainfarm.plugins import OBJECTIVES, load_plugins
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, decode_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.wire import Timings


class EpisodeStatus(StrEnum):
    ok = "ok"  # the episode ran to its end
    diverged = "diverged"  # it was stopped early; its log and penalised scores still count
    failed = "failed"  # it could not run (an unreachable path, a damaged log every attempt)
    lost = "lost"  # no result came after every attempt


@dataclass(frozen=True)
class EpisodeResult:
    """One job's outcome: one episode, not a candidate's evaluation (which takes an episode per
    trajectory, and is what "evaluations" count). `scores` is set when the episode ran (ok or
    diverged), and `log` when its MCAP log was kept."""

    job_id: str
    spec: EpisodeSpec
    status: EpisodeStatus
    scores: Scores | None
    log: Path | None
    reason: str
    worker: str
    attempts: int
    timings: Timings | None
    digest: str | None = None  # the log's SHA-256: replicas of an episode agree bit for bit


# What an evaluator does with a log: (content, spec, where to keep it, whose it is) → its scores.
ReadLog = Callable[[bytes, EpisodeSpec, Path | None, str], Scores]


def accept_log(content: bytes, spec: EpisodeSpec, path: Path | None, source: str) -> Scores:
    """What every evaluator does with an episode's log: decode it, check that it is the episode
    of `spec`, keep it at `path` (atomically; not at all without a path) and score it.
    NotAnEpisodeLog, naming `source`, if it is not a whole log of that episode."""
    episode = decode_episode(content, source)
    if episode.metadata.spec not in (spec, written_out(spec)):  # as given, or as a worker ran it
        raise NotAnEpisodeLog("the log is of another episode than the one submitted")
    if path is not None:
        write_atomically(path, content)
    return score(episode, load_plugins(OBJECTIVES, spec.objectives))  # a plug-in's too


@dataclass(frozen=True)
class Wanted:
    """A log to fetch: the episode's spec, its SHA-256 (the one the broker took, or the one
    validation found standing) and the workers that may keep it, asked in turn. `scores`: those
    its worker claimed; an evaluator whose workers are its own (`trusted`) takes them as the
    log's instead of decoding and scoring it again (most of what a fetch costs)."""

    spec: EpisodeSpec
    digest: str
    holders: tuple[str, ...]
    scores: Scores | None = None


@dataclass(frozen=True)
class Fetched:
    """A fetched log, kept at `log` and scored here (None, with `reason`, if none could be had).
    `digest` is the log's; another than the one wanted only if the episode had to be simulated
    again and came out different."""

    log: Path | None
    scores: Scores | None
    digest: str | None
    reason: str = ""
    source: str = ""  # the worker the log came from (the one that ran it again, if it had to)


class Evaluator(Protocol):
    """Runs episodes for a tuning run. Every job submitted yields exactly one evaluation (unless
    cancelled). A kept log is at RUN/episodes/<job id>.mcap, RUN being the run directory the
    evaluator was made for: the run prunes and indexes logs by that convention. One that has an
    attribute `trusted`, true, runs episodes in this process or on its own workers: a run does
    not referee its front (analytic.evaluators.replication); any other is refereed."""

    @property
    def capacity(self) -> int:
        """How many jobs can run at once now (a farm's workers): how many to keep in flight."""
        ...

    def submit(
        self, specs: Mapping[str, EpisodeSpec], avoid: Mapping[str, Sequence[str]] | None = None
    ) -> None:
        """Queue one job per (job id, spec); a job id may not be pending already. `avoid` names,
        per job id, workers that may not run it (a replica must run elsewhere)."""
        ...

    def distrust(self, worker: str) -> None:
        """Give `worker` none of this evaluator's jobs from now on (it returned a false log)."""
        ...

    def results(self, timeout: float | None = None) -> Iterator[EpisodeResult]:
        """Evaluations of the submitted jobs as they complete, until none is pending (or, with
        `timeout`, until that many seconds pass)."""
        ...

    def cancel(self, job_ids: Iterable[str]) -> None:
        """Forget these jobs: no evaluation of them will be yielded (a run that stops drops
        what it still has in flight)."""
        ...

    def fetch(
        self, wanted: Mapping[str, Wanted], simulate_again: bool = True
    ) -> dict[str, Fetched]:
        """The logs of these jobs (by job id), kept at RUN/episodes/<job id>.mcap and scored
        here: those an evaluator did not keep as their evaluations came (a farm whose workers
        keep the logs). A log nobody has any more is simulated again, unless `simulate_again`
        is false (then it is a Fetched without a log, and why)."""
        ...
