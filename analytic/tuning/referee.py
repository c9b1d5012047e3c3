"""The referee's duties in a run (the ruling itself is analytic.evaluators.replication's, pure):
who referees (nobody where the farm is trusted or the config says not to), the spot checks'
rate, the episodes checked as they arrive (spot checks and failure checks), the default gains'
episodes, and the front's, all refereed before the run reports its front; what each check ruled,
in the run's state, and the logs the referee made that the run was not told to keep dropped."""

import dataclasses
from collections.abc import Iterable
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus, Evaluator
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.replication import (
    Check,
    Ran,
    Ruling,
    Validation,
    claims_failure,
    sized_rate,
    spot_checked,
    validate,
)
from gainfarm.analytic.tuning.books import Books
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.front import FrontEpisodes
from gainfarm.analytic.tuning.jobs import planned_episodes
from gainfarm.analytic.tuning.rewinds import Rewinds
from gainfarm.analytic.tuning.state import RunState


class Refereeing:
    """The referee's part in the run in `directory`: its checks, their rulings in `state`."""

    def __init__(
        self,
        directory: Path,
        config: RunConfig,
        state: RunState,
        books: Books,
        front: FrontEpisodes,
        rewinds: Rewinds,
    ):
        self.directory = directory
        self.config = config
        self.state = state
        self.books = books
        self.front = front
        self.rewinds = rewinds

    def referee(self, evaluator: Evaluator, referee: Evaluator | None) -> Evaluator | None:
        """Who checks the workers: None when nobody need (the config says not to, or the
        evaluator runs episodes in this process or on its own workers), saying why in the
        records."""
        if not self.config.replicate:
            self.state.unchecked = "validation off (replicate: false)"
            return None
        if getattr(evaluator, "trusted", False):
            self.state.unchecked = "trusted: run in this process or by its own workers"
            return None
        self.state.unchecked = ""
        return referee or InProcessEvaluator(self.directory, models=self.books.models())

    def size_spot_checks(self, evaluator: Evaluator) -> None:
        """Fix the spot checks' rate as the run first starts: the config's, or sized so that a
        worker doing its share of the planned episodes (over the farm's workers now) and lying
        on a tenth of them is caught with probability 0.99 (replication.sized_rate). A run that
        converges later than it could only checks more lies at that rate."""
        planned, workers = planned_episodes(self.config), max(1, evaluator.capacity)
        self.state.spot_plan = (planned, workers)
        if self.config.spot_checks is None:
            self.state.spot_rate = sized_rate(planned / workers)
        else:
            self.state.spot_rate = self.config.spot_checks

    def pending(self) -> bool:
        """Whether a front member's episodes are still to be refereed: a run stopped (Ctrl-C)
        while its front was being validated, whose `run()` goes on with it."""
        if not self.config.replicate or self.state.unchecked:
            return False
        return any(
            ran.job_id not in self.state.validated
            for member in self.state.evolution.front()
            for ran in self.state.provenance.get(member.gains, ())
        )

    # --- as episodes arrive ------------------------------------------------------------------

    def check_arrivals(
        self,
        evaluator: Evaluator,
        referee: Evaluator | None,
        results: dict[str, EpisodeResult],
        *job_ids: str,
    ) -> bool:
        """The referee runs again those of `job_ids` the spot checks draw, and every failure a
        worker claims (a claim no score betrays: it would sink a good candidate unchecked);
        each takes the referee's standing evaluation in `results` (its own where it contradicts
        the worker's, a failure where it could not run it). True if it caught a worker lying."""
        if referee is None:
            return False
        rate = self.state.spot_rate or 0.0
        drawn = [
            results[job_id]
            for job_id in job_ids
            if results[job_id].digest and rate and spot_checked(self.state.spot_key, job_id, rate)
        ]
        failures = [results[job_id] for job_id in job_ids if claims_failure(results[job_id])]
        if not drawn and not failures:
            return False
        caught = False
        for check, originals in ((Check.spot_checked, drawn), (Check.failure_checked, failures)):
            if originals:
                caught |= self._referee_arrivals(evaluator, referee, results, check, originals)
        return caught

    def _referee_arrivals(
        self,
        evaluator: Evaluator,
        referee: Evaluator,
        results: dict[str, EpisodeResult],
        check: Check,
        drawn: list[EpisodeResult],
    ) -> bool:
        """`check_arrivals`' work for one kind of check: True if it caught a worker lying."""
        validation = validate(evaluator, drawn, self.state.ledger, referee=referee, check=check)
        self._note_checks(check, validation, {e.job_id: e.worker for e in drawn})
        for result in drawn:
            job_id = result.job_id
            if job_id in validation.standing:
                results[job_id] = validation.standing[job_id]
            else:  # unsettled: it fails, as a front member the referee cannot run does
                reason = "the referee could not run it again"
                results[job_id] = dataclasses.replace(
                    result, status=EpisodeStatus.failed, scores=None, digest=None, reason=reason
                )
        return Ruling.contradicted in validation.rulings.values()

    def _note_checks(self, check: Check, validation: Validation, workers: dict[str, str]) -> None:
        self.state.validated.update(validation.rulings)
        for job_id, ruling in validation.rulings.items():
            self.state.checks[job_id] = (check.value, ruling.value, workers[job_id])

    # --- the default gains' episodes -----------------------------------------------------------

    def referee_baseline(
        self, evaluator: Evaluator, found: dict[str, EpisodeResult]
    ) -> dict[str, str]:
        """On a farm not its own, the referee runs every episode of the default gains: report.md
        and the held-out check measure the front against them, so one forged episode would turn
        the advice. Each takes the referee's standing evaluation in `found` (its own where it
        contradicts the worker's); returns the rulings, by job id."""
        referee = self.referee(evaluator, None)
        if referee is None:
            return {}
        validation = validate(
            evaluator,
            list(found.values()),
            self.state.ledger,
            referee=referee,
            check=Check.baseline,
        )
        for job_id in validation.unsettled:  # the referee cannot run it: it fails
            found[job_id] = dataclasses.replace(
                found[job_id], status=EpisodeStatus.failed, scores=None, digest=None
            )
        found.update(validation.standing)
        self.drop_refereed_logs(validation.standing.values())
        return {job_id: ruling.value for job_id, ruling in validation.rulings.items()}

    def drop_refereed_logs(self, evaluations: Iterable[EpisodeResult]) -> None:
        """With --keep front, the logs the referee made of episodes no front member has (the
        default gains', the held-out check's) go once ruled on: the run keeps the logs it was
        told to keep, whoever made them. Their records keep the rulings and the scores."""
        if self.config.keep != "front":
            return
        for result in evaluations:
            if result.log is not None:
                result.log.unlink(missing_ok=True)

    # --- the front, before the run reports it --------------------------------------------------

    def validate_front(self, evaluator: Evaluator, referee: Evaluator) -> bool:
        """Before the run reports its front, the referee runs every front member's episodes
        again (analytic.evaluators.replication). A worker it contradicts is caught: a
        generational run starts again without its results (True: the run goes on). Otherwise
        a member whose worker it contradicts takes the referee's objectives; one it cannot run
        fails (the penalty), never reported as validated. Either can uncover a candidate it had
        falsely dominated, so this goes on until every member of the front is validated.
        Records and checkpoint are written again if anything was checked."""
        state = self.state
        checked = corrected = False
        while True:
            todo = {
                member.gains: state.provenance.get(member.gains, ())
                for member in state.evolution.front()
            }
            originals = [
                self.front.original(gains, ran)
                for gains, episodes in todo.items()
                for ran in episodes
                if ran.job_id not in state.validated
            ]
            if not originals:
                break
            checked = True
            validation = validate(evaluator, originals, state.ledger, referee=referee)
            self._note_checks(Check.refereed, validation, {e.job_id: e.worker for e in originals})
            if self.rewinds.due(evaluator):
                self.rewinds.rewind(evaluator)
                return True
            standing = validation.standing
            for gains, episodes in todo.items():
                now = tuple(
                    Ran(r.job_id, r.worker, None, None)  # unsettled: failed
                    if r.job_id in validation.unsettled
                    else Ran.of(standing[r.job_id])
                    if r.job_id in standing
                    else r
                    for r in episodes
                )
                if now != episodes:
                    corrected = True
                    self.front.correct(gains, now)
                    self.front.drop_stale_logs(gains, now)
                self.front.keep_refereed(gains, [standing.get(r.job_id) for r in now])
        if self.front.fetch(evaluator):
            checked = corrected = True
            if self.rewinds.due(evaluator):
                self.rewinds.rewind(evaluator)
                return True
        if checked:
            if corrected and state.history:  # the last row says what the run reports
                state.history[-1] = self.books.row_of(state.evolution.front(), state.history[-1])
            self.books.save()  # the records and the checkpoint agree
        return False
