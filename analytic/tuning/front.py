"""The front's episodes as they truly ran: the logs a farm's workers keep, fetched and scored here
again (a member whose log does not score as its worker claimed takes the log's scores, and that
worker is distrusted), a member's objectives corrected wherever the run keeps them, and the logs
kept here that match what stands."""

import hashlib
import logging
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus, Evaluator, Wanted
from gainfarm.analytic.evaluators.replication import Ran
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.jobs import candidate_objectives, episode_spec
from gainfarm.analytic.tuning.records import EPISODES
from gainfarm.analytic.tuning.state import RunState
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.limits import measures

log = logging.getLogger("gainfarm.analytic")


class FrontEpisodes:
    """The episodes of a run's front members, in its directory and state."""

    def __init__(self, directory: Path, config: RunConfig, state: RunState):
        self.directory = directory
        self.config = config
        self.state = state

    def fetch(self, evaluator: Evaluator, simulate_again: bool = True) -> bool:
        """Fetch the logs of front members that have none here (an evaluator whose workers keep
        the logs: analytic.farm), each scored here again. A member whose log does not score as
        its worker claimed takes the log's scores, and that worker is distrusted; the front can
        move, so this goes on until every member has its logs. True if a member was corrected.
        Without `simulate_again`, a log its worker no longer keeps is left for a later fetch.
        """
        state = self.state
        corrected = False
        tried: set[str] = set()
        while True:
            wanted = {
                ran.job_id: (member.gains, ran)
                for member in state.evolution.front()
                for ran in state.provenance.get(member.gains, ())
                if ran.job_id not in state.episodes.get(member.gains, ())
                and ran.digest is not None
                and ran.scores is not None
                and ran.job_id not in tried
            }
            if not wanted:
                return corrected
            tried.update(wanted)
            fetched = evaluator.fetch(
                {
                    job_id: Wanted(
                        episode_spec(self.config, gains, job_id),
                        ran.digest,
                        (ran.worker,),
                        ran.scores,
                    )
                    for job_id, (gains, ran) in wanted.items()
                    if ran.digest is not None
                },
                simulate_again,
            )
            changed: dict[PDGains, list[Ran]] = {}
            for job_id, got in fetched.items():
                gains, ran = wanted[job_id]
                if got.log is None:
                    if simulate_again:
                        log.warning("no log of %s could be had: %s", job_id, got.reason)
                    continue
                state.episodes.setdefault(gains, []).append(job_id)
                if got.scores != ran.scores:
                    log.error(
                        "worker %r claimed scores for %s that its log does not have: the log's "
                        "stand, and its results are no longer trusted",
                        ran.worker,
                        job_id,
                    )
                    evaluator.distrust(ran.worker)
                    true = Ran(job_id, ran.worker, got.digest, got.scores)
                    changed.setdefault(gains, list(state.provenance[gains]))
                    changed[gains] = [true if r.job_id == job_id else r for r in changed[gains]]
            for gains, now in changed.items():
                corrected = True
                self.correct(gains, tuple(now))

    def correct(self, gains: PDGains, standing: tuple[Ran, ...]) -> None:
        """A candidate's episodes as they truly ran, and the objectives they give, everywhere
        the run keeps them: evaluated.csv holds the points in the order told, so the true one
        replaces the false one there too, and the cloud and the front agree."""
        self.state.provenance[gains] = standing
        scores = [ran.scores for ran in standing]
        true = candidate_objectives(self.config, scores)
        measured = measures(scores)
        g = self.config.limits.constraints(measured)
        for row in self.state.evolution.correct(gains, true, g):
            self.state.evaluated[row] = true
            self.state.measured[row] = measured

    def keep_refereed(self, gains: PDGains, standing: list[EpisodeResult | None]) -> None:
        """A member's logs validation left here (the referee's, where the worker's is not
        here) are kept, as fetched ones are: nothing to fetch."""
        kept = self.state.episodes.setdefault(gains, [])
        for result in standing:
            if result is not None and result.log is not None and result.job_id not in kept:
                kept.append(result.job_id)

    def drop_stale_logs(self, gains: PDGains, standing: tuple[Ran, ...]) -> None:
        """Validation outvoted some of a member's episodes: a log kept here that is not the
        standing one's (a log fetched from the outvoted worker) goes, to be fetched anew."""
        kept = self.state.episodes.get(gains, [])
        for ran in standing:
            path = self.directory / EPISODES / f"{ran.job_id}.mcap"
            if ran.job_id in kept and (
                not path.exists() or hashlib.sha256(path.read_bytes()).hexdigest() != ran.digest
            ):
                path.unlink(missing_ok=True)
                kept.remove(ran.job_id)

    def original(self, gains: PDGains, ran: Ran) -> EpisodeResult:
        """An original as validation takes it: the episode's spec, who ran it, its log."""
        spec = episode_spec(self.config, gains, ran.job_id)
        log = self.directory / EPISODES / f"{ran.job_id}.mcap"
        return EpisodeResult(
            job_id=ran.job_id,
            spec=spec,
            status=EpisodeStatus.ok,
            scores=ran.scores,
            log=log if log.exists() else None,
            reason="",
            worker=ran.worker,
            attempts=1,
            timings=None,
            digest=ran.digest,
        )
