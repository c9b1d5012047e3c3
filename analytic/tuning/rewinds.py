"""What a caught worker costs a run: whom it distrusts, whether a trusted worker is left to run
its episodes (the run stops when none is), and the rewind, a generational run starting its
evolution again from its seed without the caught workers' results (job ids then start `r<n>-`),
taking every other result as it ran."""

import logging
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.tuning.books import Books
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import EPISODES
from gainfarm.analytic.tuning.state import RunState, evolution_of
from gainfarm.edges.files import interrupts_deferred
from gainfarm.schemas.gains import PDGains

log = logging.getLogger("gainfarm.analytic")


class Rewinds:
    """The distrusted workers of a run, and its rewinds without them."""

    def __init__(self, directory: Path, config: RunConfig, state: RunState, books: Books):
        self.directory = directory
        self.config = config
        self.state = state
        self.books = books
        self._said_alone: set[str] = set()  # caught workers with nobody to run their episodes

    def prefix(self) -> str:
        """Job ids after a rewind are new ones: a log of the run before is never overwritten."""
        return f"r{self.state.rewinds}-" if self.state.rewinds else ""

    def distrusted(self, evaluator: Evaluator) -> set[str]:
        return {*self.state.ledger.dissenters, *getattr(evaluator, "distrusted", ())}

    def known(self, gains: PDGains, evaluator: Evaluator) -> bool:
        """Whether a candidate of a rewound run was evaluated before by workers still trusted:
        its episodes are deterministic, so they are not run again. (Before any rewind, a run
        evaluates whatever it is asked, as it always did.)"""
        if not self.state.rewinds or gains not in self.state.provenance:
            return False
        distrusted = self.distrusted(evaluator)
        return not any(ran.worker in distrusted for ran in self.state.provenance[gains])

    def caught(self, evaluator: Evaluator) -> set[str]:
        """Distrusted workers whose results the run still holds."""
        ran = {ran.worker for episodes in self.state.provenance.values() for ran in episodes}
        return ran & self.distrusted(evaluator)

    @staticmethod
    def trusted_left(evaluator: Evaluator, distrusted: set[str]) -> bool:
        """Whether a worker not distrusted is there to run episodes: by name where the
        evaluator knows them (FarmClient.trusted_capacity: a caught worker may have gone),
        else by count."""
        trusted = getattr(evaluator, "trusted_capacity", None)
        if trusted is not None:
            return trusted > 0
        return evaluator.capacity > len(distrusted)

    def nobody_left(self, evaluator: Evaluator) -> bool:
        """Stop the run when every worker of the farm is distrusted: nobody is left to run its
        episodes (they would wait out every deadline)."""
        distrusted = self.distrusted(evaluator)
        if not distrusted or self.trusted_left(evaluator, distrusted):
            return False
        self.state.stopped = f"no trusted worker left ({', '.join(sorted(distrusted))} lied)"
        log.error("every worker of the farm is distrusted: the run stops")
        self.books.save()
        return True

    def due(self, evaluator: Evaluator) -> bool:
        """Whether to start again without the caught workers' results: in a generational run
        (a steady state's order is the farm's: it would not retrace), with workers left to run
        their episodes again (else the referee's corrections of the front are all there is)."""
        caught = self.caught(evaluator)
        if not caught or self.config.asynchronous:
            return False
        if self.trusted_left(evaluator, self.distrusted(evaluator)):
            return True
        if caught - self._said_alone:  # once per worker, not every generation
            self._said_alone |= caught
            log.error(
                "%s lied about episodes and no other worker is left to run them again: only "
                "the front is corrected, by the referee",
                ", ".join(sorted(caught)),
            )
        return False

    def rewind(self, evaluator: Evaluator) -> None:
        """Start the evolution again from its seed without the caught workers' results: what
        they ran is forgotten (and runs again, on the workers still trusted, when it is asked
        again); everything else is taken as it was. A generational run is deterministic given
        what it is told, so this retraces the run an honest farm would have made."""
        state = self.state
        caught = self.caught(evaluator)
        for gains, episodes in list(state.provenance.items()):
            if any(ran.worker in caught for ran in episodes):
                del state.provenance[gains]
                for job_id in state.episodes.pop(gains, []):
                    (self.directory / EPISODES / f"{job_id}.mcap").unlink(missing_ok=True)
        state.evolution = evolution_of(self.config)
        state.history.clear()
        state.evaluated.clear()
        state.measured.clear()
        state.stopped = None
        state.rewinds += 1
        log.warning(
            "%s lied about episodes: the evolution starts again from its seed without their "
            "results (rewind %d); the rest are taken as they ran",
            ", ".join(sorted(caught)),
            state.rewinds,
        )
        with interrupts_deferred():
            self.books.checkpoint()
