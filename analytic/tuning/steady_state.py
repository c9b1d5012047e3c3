"""The steady-state (asynchronous) loop's step: each candidate told as its episodes return and a
new one asked at once, two per worker in flight so that none waits. Its order is the farm's, so
it is never rewound: a worker caught here is distrusted and its results that reach the front are
refereed, but its earlier ones stand."""

import math
import time
from collections.abc import Callable

from pymoo.core.population import Population

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Evaluator
from gainfarm.analytic.tuning.generational import Loop
from gainfarm.analytic.tuning.jobs import job_ids, specs
from gainfarm.analytic.tuning.state import RunProgress
from gainfarm.schemas.gains import PDGains

# A steady-state run asks the farm how many workers it has this often: a broker status query
# per evaluation would cost more than the evaluation.
CAPACITY_SECONDS = 2.0


class SteadyState(Loop):
    """A steady-state run after its first generation, one `step` until it stops."""

    def step(
        self,
        evaluator: Evaluator,
        started: float,
        on_progress: Callable[[RunProgress], None],
        referee: Evaluator | None,
    ) -> None:
        """Keep two candidates per worker in flight so that none waits, as many workers as the
        farm has now (looked up again every CAPACITY_SECONDS: workers come and go, and a farm
        that grows mid-run is used); a "generation" here is every `pop` evaluations, for the
        history, the termination and the checkpoint. A budget of evaluations is kept exactly:
        no candidate is asked beyond it, and the last, partial "generation" ends with it. When
        the run stops, the candidates still in flight are dropped (a resumed run asks anew).
        A candidate's spot checks are run before it is told; a steady state is not replayed
        (its order is the farm's), so a worker caught here is distrusted and its results that
        reach the front are refereed, but its earlier ones stand."""
        evolution = self.state.evolution
        books = self.books
        in_flight: dict[str, tuple[Population, PDGains, list[str]]] = {}
        results: dict[str, EpisodeResult] = {}

        def launch() -> None:
            handle, gains = evolution.ask_one()
            self.state.serial += 1
            name = f"s{self.state.serial:06d}"
            in_flight[name] = (handle, gains, job_ids(self.config, name))
            evaluator.submit(specs(self.config, {gains: in_flight[name][2]}))

        wanted, looked = 0, -math.inf
        budget = self.config.evaluations or math.inf

        def top_up() -> None:
            nonlocal wanted, looked
            if time.monotonic() - looked >= CAPACITY_SECONDS:
                wanted, looked = max(2, 2 * evaluator.capacity), time.monotonic()
            while len(in_flight) < wanted and evolution.evaluations + len(in_flight) < budget:
                launch()

        try:
            top_up()
            for result in evaluator.results():
                name = result.job_id.rsplit("-t", 1)[0]
                results[result.job_id] = result
                books.account(result)
                handle, gains, ids = in_flight[name]
                if not all(job_id in results for job_id in ids):
                    continue
                del in_flight[name]
                caught = self.refereeing.check_arrivals(evaluator, referee, results, *ids)
                if caught and self.rewinds.nobody_left(evaluator):
                    return
                books.record(gains, ids, results)
                evolution.tell_one(handle, *books.candidate_done(gains))
                on_progress(books.progress(0, started))
                if evolution.evaluations % self.config.pop == 0 or evolution.evaluations >= budget:
                    books.generation_done(started, evaluator)
                    on_progress(books.progress(0, started, ended=True))
                    if self.state.stopped is not None:
                        return
                top_up()
        finally:
            evaluator.cancel(
                [
                    job_id
                    for _, _, ids in in_flight.values()
                    for job_id in ids
                    if job_id not in results
                ]
            )
