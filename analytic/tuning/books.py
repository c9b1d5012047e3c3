"""A run's books: what it keeps of each candidate (its episodes as they ran, its point as told),
a generation's end (the history row, the front's logs pruned or fetched, whether the termination
stops it), and the files that say it all (the records, the checkpoint, and the feed-forward model
the run serves), written through the run's lock."""

import dataclasses
import math
import time
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Evaluator
from gainfarm.analytic.evaluators.replication import LIE_SHARE, Ran, caught_probability
from gainfarm.analytic.tuning.checkpoint import encode
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import declarations, maximised
from gainfarm.analytic.tuning.evolution import Candidate, hypervolume
from gainfarm.analytic.tuning.front import FrontEpisodes
from gainfarm.analytic.tuning.jobs import candidate_objectives
from gainfarm.analytic.tuning.records import (
    EPISODES,
    EVALUATED_CSV,
    FEEDFORWARD,
    FRONT_CSV,
    FRONT_JSON,
    HISTORY_CSV,
    PROVENANCE_CSV,
    EpisodeCheck,
    FrontMember,
    HistoryRow,
    RunIdentity,
    ValidationRecord,
    best_of,
    evaluated_csv,
    front_csv,
    front_json,
    history_csv,
    provenance_csv,
)
from gainfarm.analytic.tuning.state import RunProgress, RunState
from gainfarm.analytic.tuning.termination import expected_generations
from gainfarm.cli.words import counted
from gainfarm.edges.files import Lock, interrupts_deferred, write_atomically
from gainfarm.models.dynamics import MAX_FILE_BYTES as MAX_MODEL_BYTES
from gainfarm.models.dynamics import digest
from gainfarm.schemas.documents import read_bounded
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.limits import measures

CHECKPOINT = "checkpoint.pkl"
# The records and the checkpoint are written as a generation ends, unless they were written less
# than this long ago: writing them costs some 20-40 ms of CPU (most of it pickling the optimiser
# and every episode's provenance), a millisecond per evaluation for fast generations of 30
# (bench/analytic_cost.py). A run interrupted runs again at most this long's generations when it
# resumes, to the same (deterministic) front; one that stops is written whatever the time.
RECORD_SECONDS = 10.0


class Books:
    """The books of the run in `directory`, whose `lock` this process holds while it writes."""

    def __init__(
        self,
        directory: Path,
        config: RunConfig,
        state: RunState,
        identity: RunIdentity,
        lock: Lock,
        front: FrontEpisodes,
    ):
        self.directory = directory
        self.config = config
        self.state = state
        self.identity = identity
        self.lock = lock
        self.front = front
        self._records_due = -math.inf  # when a generation's end next writes the records
        self._expected: int | None = None  # evaluations, as RunProgress.expected
        # What the checkpoint on disk holds: a Ctrl-C says this, not the generation reached,
        # since the records are written at most every RECORD_SECONDS and a resume starts from
        # them. (Not written on the way out: mid-generation the optimiser has already been
        # asked for the next candidates, and keeping a copy of every ended generation's state
        # would cost the pickling RECORD_SECONDS saves.)
        self.saved_generations = len(state.history)
        self.saved_stopped = state.stopped is not None

    def check_open(self) -> None:
        """RuntimeError unless this object holds the run's lock, which writing needs."""
        if not self.lock.held:
            raise RuntimeError(f"{self.directory}: this run was closed; open it again to write")

    def models(self) -> dict[str, bytes]:
        """The feed-forward model the run's episodes use, by SHA-256, to serve to the workers
        (ValueError if the run directory's copy is missing or not the one the config names)."""
        wanted = self.config.feedforward
        if wanted is None:
            return {}
        try:
            raw = read_bounded(self.directory / FEEDFORWARD, MAX_MODEL_BYTES)
        except OSError as error:
            raise ValueError(
                f"{FEEDFORWARD}: cannot read the run's model ({error.strerror})"
            ) from None
        if digest(raw) != wanted:
            raise ValueError(f"{FEEDFORWARD} is not the model config.json names")
        return {wanted: raw}

    # --- each candidate ------------------------------------------------------------------------

    def account(self, result: EpisodeResult) -> None:
        if result.timings is not None:
            timings = result.timings
            self.state.busy_seconds += timings.simulate_s + timings.encode_s

    def record(self, gains: PDGains, job_ids: list[str], results: dict[str, EpisodeResult]) -> None:
        """A candidate's episodes as they ran, and the logs of them kept here."""
        self.state.episodes[gains] = [i for i in job_ids if results[i].log is not None]
        self.state.provenance[gains] = tuple(Ran.of(results[job_id]) for job_id in job_ids)

    def candidate_done(self, gains: PDGains) -> tuple[tuple[float, float], tuple[float, ...]]:
        """A recorded candidate's objectives and constraint values (schemas.limits: its worst
        measures over all its episodes), with its point recorded as told."""
        scores = [ran.scores for ran in self.state.provenance[gains]]
        found = candidate_objectives(self.config, scores)
        measured = measures(scores)
        self.state.evaluated.append(found)
        self.state.measured.append(measured)
        return found, self.config.limits.constraints(measured)

    def progress(
        self, evaluations_in_flight: int, started: float, ended: bool = False
    ) -> RunProgress:
        best = self.state.history[-1] if self.state.history else None
        return RunProgress(
            generation=best.generation if ended and best else self.state.evolution.generation,
            evaluations=self.state.evolution.evaluations + evaluations_in_flight,
            hypervolume=best.hypervolume if best else math.nan,
            best_f_acc=best.best_f_acc if best else math.nan,
            elapsed=time.monotonic() - started,
            ended=ended,
            budget=self.config.budget,
            expected=self._expected,
        )

    # --- each generation -----------------------------------------------------------------------

    def generation_done(self, started: float, evaluator: Evaluator) -> None:
        """History row, front, its logs (pruned, or fetched), whether it stops (the termination)
        and checkpoint."""
        state = self.state
        front = state.evolution.front()
        state.wall_seconds = time.monotonic() - started
        generation = state.evolution.generation
        if self.config.asynchronous and state.evolution.evaluations % self.config.pop:
            generation += 1  # the last, partial one, which a budget of evaluations ended
        state.history.append(
            HistoryRow(
                generation=generation,
                evaluations=state.evolution.evaluations,
                hypervolume=hypervolume(
                    [member.objectives for member in front], self.config.reference_point
                ),
                best=best_of([member.objectives for member in front], self.config.objectives),
                wall_seconds=state.wall_seconds,
                names=self.config.objectives,
            )
        )
        if self.config.keep == "front":
            keep = {member.gains for member in front}
            for gains in [gains for gains in state.episodes if gains not in keep]:
                for job_id in state.episodes.pop(gains):
                    (self.directory / EPISODES / f"{job_id}.mcap").unlink(missing_ok=True)
        due = time.monotonic() >= self._records_due
        # Fetching checks a farm's claims as the front takes them in; its own workers' claims
        # stand (`trusted`), so their logs are fetched only for the records that list them,
        # and only the final records simulate again a log its worker has let go: with dozens
        # of runs sharing a farm (an experiment's), the workers' stores turn over within a
        # generation, and simulating every new member again for records written every 10 s
        # cost 12 % more episodes (912 of 7,400 in generic-vs-specific's 70 runs).
        trusted = getattr(evaluator, "trusted", False)
        stopping = self.stops() is not None
        fetch = not trusted or due or stopping
        if fetch and self.front.fetch(evaluator, simulate_again=not trusted or stopping):
            front = state.evolution.front()  # a member's scores were false: the front moved
            state.history[-1] = self.row_of(front, state.history[-1])
        state.stopped = self.stops()
        # Fitted once a generation, not at every evaluation's progress line.
        expected = expected_generations(
            self.config.termination, [row.hypervolume for row in state.history]
        )
        self._expected = None if expected is None else expected * self.config.pop
        if state.stopped is None and not due:
            return
        # A Ctrl-C between history.csv and the checkpoint would leave them a generation apart.
        self.save()
        self._records_due = time.monotonic() + RECORD_SECONDS

    def stops(self) -> str | None:
        """Why the run stops now (the termination's reason, from its history), or None."""
        hypervolumes = [row.hypervolume for row in self.state.history]
        return self.config.termination.reason(hypervolumes, self.state.evolution.evaluations)

    def row_of(self, front: list[Candidate], row: HistoryRow) -> HistoryRow:
        """`row` with the hypervolume and bests of `front` (after a correction)."""
        points = [member.objectives for member in front]
        return dataclasses.replace(
            row,
            hypervolume=hypervolume(points, self.config.reference_point),
            best=best_of(points, self.config.objectives),
        )

    # --- the files ---------------------------------------------------------------------------

    def save(self) -> None:
        """The records, then the checkpoint, with a Ctrl-C held off until both are written: so
        that they agree."""
        with interrupts_deferred():
            self.write_records()
            self.checkpoint()

    def checkpoint(self) -> None:
        write_atomically(self.directory / CHECKPOINT, encode(self.state, self.identity))
        self.saved_generations = len(self.state.history)
        self.saved_stopped = self.state.stopped is not None

    def write_records(self) -> None:
        """The plain files of where the run stands (analytic.records), history.csv last: a
        reader that finds a generation in history.csv finds its front and points too. (A crash
        between history.csv and the checkpoint leaves the plain files a generation ahead: a
        resume runs that generation again, to the same, deterministic, result.)"""
        self.check_open()
        names = self.config.objectives
        rows = front_rows(self.state, names)
        write_atomically(
            self.directory / EVALUATED_CSV,
            evaluated_csv(
                self.state.evaluated, self.state.measured, self.config.limits, declarations(names)
            ),
        )
        write_atomically(self.directory / FRONT_JSON, front_json(rows, self.validation()))
        write_atomically(self.directory / PROVENANCE_CSV, provenance_csv(rows))
        joints = len(self.config.arm.joint_names)
        write_atomically(self.directory / FRONT_CSV, front_csv(rows, names, joints))
        write_atomically(self.directory / HISTORY_CSV, history_csv(self.state.history, names))

    def validation(self) -> ValidationRecord:
        """What validation found over the run, as its records say it."""
        ledger, state = self.state.ledger, self.state
        rate = (state.spot_rate or 0.0) if self.config.replicate else 0.0
        return ValidationRecord(
            refereed=ledger.refereed,
            spot_checked=ledger.spot_checked,
            spot_check_rate=rate,
            spot_check_guarantee=self._guarantee() if self.config.replicate else "",
            failures_checked=ledger.failures_checked,
            baseline_refereed=ledger.baseline,
            held_out_refereed=ledger.held_out,
            disagreements=ledger.disagreements,
            unsettled=ledger.unsettled,
            distrusted=dict(ledger.dissenters),
            rewinds=state.rewinds,
            unchecked=state.unchecked,
        )

    def _guarantee(self) -> str:
        """What the spot checks' rate buys, in words, for the records."""
        rate, plan = self.state.spot_rate, self.state.spot_plan
        if rate is None or plan is None:
            return ""
        if not rate:
            return "spot checks off (--spot-checks 0): only the front and failures are refereed"
        planned, workers = plan
        share = planned / workers
        chance = caught_probability(rate, share)
        how = "set by hand" if self.config.spot_checks is not None else "sized"
        return (
            f"{how}: a worker lying on {LIE_SHARE:.0%} of its share of the run's episodes "
            f"({share:g}: {planned} planned over {counted(workers, 'worker')}) is caught with "
            f"probability {chance:.3g}"
        )


def front_rows(state: RunState, names: tuple[str, ...]) -> list[FrontMember]:
    """The front as the record keeps it: gains, objectives (named `names`), whether an episode
    diverged, and the logs kept of each member."""
    return [
        FrontMember(
            member.gains.kp,
            member.gains.kd,
            member.objectives,
            names=names,
            maximised=maximised(names),
            logs=tuple(f"{EPISODES}/{job}.mcap" for job in state.episodes.get(member.gains, [])),
            diverged=any(
                ran.scores is not None and ran.scores.diverged
                for ran in state.provenance.get(member.gains, ())
            ),
            episodes=tuple(_checked(state, ran) for ran in state.provenance.get(member.gains, ())),
            measures=_measures(state.provenance.get(member.gains, ())),
        )
        for member in state.evolution.front()
    ]


def _measures(episodes: tuple[Ran, ...]) -> tuple[float, ...]:
    """A member's safety measures over its episodes (none known without its provenance)."""
    return measures([ran.scores for ran in episodes]) if episodes else ()


def _checked(state: RunState, ran: Ran) -> EpisodeCheck:
    """Who ran an episode, and how it was checked (or why it was not)."""
    if ran.job_id in state.checks:
        check, ruling, worker = state.checks[ran.job_id]
        return EpisodeCheck(ran.job_id, worker, check, ruling)
    if ran.digest is None:
        why = "it did not run"
    else:
        why = state.unchecked or "not yet: the run has not validated its front"
    return EpisodeCheck(ran.job_id, ran.worker, "not checked", why)
