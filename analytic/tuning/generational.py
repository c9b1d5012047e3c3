"""The generational loop's step: a whole generation out to the evaluator, each episode checked
by the referee as it arrives, then every candidate told in the order asked (so a generational run
is deterministic given what it is told, and a rewind retraces it)."""

from collections.abc import Callable
from dataclasses import dataclass

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Evaluator
from gainfarm.analytic.tuning.books import Books
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.jobs import job_ids, specs
from gainfarm.analytic.tuning.referee import Refereeing
from gainfarm.analytic.tuning.rewinds import Rewinds
from gainfarm.analytic.tuning.state import RunProgress, RunState


@dataclass
class Loop:
    """What a run's loop variant works with: the run's parts, shared with `TuningRun`."""

    config: RunConfig
    state: RunState
    books: Books
    rewinds: Rewinds
    refereeing: Refereeing


class Generational(Loop):
    """A run's generations, one `step` each."""

    def step(
        self,
        evaluator: Evaluator,
        started: float,
        on_progress: Callable[[RunProgress], None],
        referee: Evaluator | None,
    ) -> None:
        evolution = self.state.evolution
        books, rewinds = self.books, self.rewinds
        if rewinds.nobody_left(evaluator):
            return
        candidates = evolution.ask()
        prefix = f"{rewinds.prefix()}g{evolution.generation:04d}"
        jobs = {
            gains: job_ids(self.config, f"{prefix}-c{index:03d}")
            for index, gains in enumerate(candidates)
        }
        known = {gains for gains in candidates if rewinds.known(gains, evaluator)}
        unknown = {gains: ids for gains, ids in jobs.items() if gains not in known}
        asked = specs(self.config, unknown)
        results: dict[str, EpisodeResult] = {}
        if asked:
            evaluator.submit(asked)
        try:
            for result in evaluator.results() if asked else ():
                results[result.job_id] = result
                books.account(result)
                # As it arrives, while the farm runs the rest; and before anything is told, so
                # a lie caught now has steered nothing yet.
                caught = self.refereeing.check_arrivals(evaluator, referee, results, result.job_id)
                if caught and rewinds.nobody_left(evaluator):  # the generation cannot finish
                    return
                on_progress(books.progress(len(results) // len(jobs[candidates[0]]), started))
        finally:  # stopped mid-generation (Ctrl-C): leave nothing queued in the evaluator
            evaluator.cancel([job_id for job_id in asked if job_id not in results])
        for gains in candidates:
            if gains not in known:
                books.record(gains, jobs[gains], results)
        if rewinds.due(evaluator):
            rewinds.rewind(evaluator)
            return
        done = [books.candidate_done(gains) for gains in candidates]
        evolution.tell([found for found, _ in done], [g for _, g in done])
        books.generation_done(started, evaluator)
        on_progress(books.progress(0, started, ended=True))
        if rewinds.due(evaluator):  # a front member's fetched log gave its worker away
            rewinds.rewind(evaluator)
