"""A tuning run: NSGA-II generations evaluated by an evaluator, recorded in a run directory.

Optuna's Study, in its shape: the evolution step (analytic.evolution) is the sampler, an evaluator
(analytic.evaluator: the farm, or this process) runs the episodes, and the run directory is the
storage. As a generation ends the run writes, each file atomically (analytic.records), unless it
wrote them less than RECORD_SECONDS ago (and always as it stops):

    config.json      everything needed to repeat the run (written once)
    run.json         the run's id (written once), which its checkpoint carries
    run.lock         held by the one process writing the run
    checkpoint.pkl   the evolution with its random state, for resuming only (analytic.checkpoint)
    history.csv      one row per generation: evaluations, hypervolume, best f_acc and f_t, wall s
    front.csv        the non-dominated gains and their objectives
    front.json       the same front with each member's episode logs
    evaluated.csv    every candidate's objectives, in the order told
    episodes/        the MCAP logs (all, or only the front's with keep="front")

and, once asked (`baseline`), baseline.json: the default gains on the run's trajectories,
evaluated once. The figures and report.md are the view's (analytic.view.run_report), drawn by
what composes the run (`tune`, an experiment's runner). A stopped run continues from its last
checkpoint; the generations since run again, with the same candidates and the same
(deterministic) episodes, so the front is the one an uninterrupted run finds.

One process writes a run at a time: `create` and `open` take the run's lock (RunBusy if another
process holds it) and keep it until `close()` (or the end of a `with`, or the process). Holding
it, they first delete what writes killed halfway left behind (edges.files.remove_leftovers).
A write that fails (disk full, read-only) raises OSError naming the file; each file is whole or
absent, the checkpoint is written last, so a later resume continues from the last good one.
"""

import dataclasses
import hashlib
import logging
import math
import secrets
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pymoo.core.population import Population

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus, Evaluator, Wanted
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.replication import (
    LIE_SHARE,
    Check,
    Ledger,
    Ran,
    Ruling,
    Validation,
    caught_probability,
    claims_failure,
    sized_rate,
    spot_checked,
    validate,
)
from gainfarm.analytic.tuning.checkpoint import CheckpointRefused, decode, encode
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import declarations, maximised
from gainfarm.analytic.tuning.evolution import Candidate, Evolution, hypervolume
from gainfarm.analytic.tuning.records import (
    BASELINE_JSON,
    CONFIG_JSON,
    EPISODES,
    EVALUATED_CSV,
    FEEDFORWARD,
    FRONT_CSV,
    FRONT_JSON,
    HISTORY_CSV,
    LOCK,
    MAX_RECORD_BYTES,
    PROVENANCE_CSV,
    RUN_JSON,
    Baseline,
    EpisodeCheck,
    FrontMember,
    HistoryRow,
    RunIdentity,
    ValidationRecord,
    baseline_json,
    best_of,
    evaluated_csv,
    front_csv,
    front_json,
    history_csv,
    provenance_csv,
    read_baseline,
    read_identity,
    run_json,
    sorted_front,
)
from gainfarm.analytic.tuning.termination import expected_generations
from gainfarm.cli.words import counted
from gainfarm.edges.files import (
    Lock,
    Locked,
    interrupts_deferred,
    remove_leftovers,
    write_atomically,
)
from gainfarm.models.dynamics import MAX_FILE_BYTES as MAX_MODEL_BYTES
from gainfarm.models.dynamics import digest
from gainfarm.schemas.documents import read_bounded
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import MEASURES, before_lag, measures
from gainfarm.schemas.objectives import no_episode, objectives

log = logging.getLogger("gainfarm.analytic")

CHECKPOINT = "checkpoint.pkl"
# Read back within this: a population's whole state is some MB, a long TPE history tens.
MAX_CHECKPOINT_BYTES = 1 << 30
# A steady-state run asks the farm how many workers it has this often: a broker status query
# per evaluation would cost more than the evaluation.
CAPACITY_SECONDS = 2.0
# The records and the checkpoint are written as a generation ends, unless they were written less
# than this long ago: writing them costs some 20-40 ms of CPU (most of it pickling the optimiser
# and every episode's provenance), a millisecond per evaluation for fast generations of 30
# (bench/analytic_cost.py). A run interrupted runs again at most this long's generations when it
# resumes, to the same (deterministic) front; one that stops is written whatever the time.
RECORD_SECONDS = 10.0


class RunBusy(Exception):
    """Another process is writing the run (a start or resume of it is running)."""

    def __init__(self, directory: Path, holder: str):
        self.directory = Path(directory)
        self.holder = holder
        by = holder or "another process"
        super().__init__(
            f"{str(self.directory)!r} is in use: {by} is running it (one start or resume of a "
            "run at a time)"
        )


@dataclass
class RunState:
    """What a checkpoint holds: enough to continue exactly where the run stood."""

    evolution: Evolution
    history: list[HistoryRow] = field(default_factory=list)
    evaluated: list[tuple[float, float]] = field(default_factory=list)
    # Each evaluated candidate's safety measures (schemas.limits.measures), in the same order.
    measured: list[tuple[float, ...]] = field(default_factory=list)
    episodes: dict[PDGains, list[str]] = field(default_factory=dict)  # job ids of kept logs
    wall_seconds: float = 0.0
    stopped: str | None = None
    serial: int = 0  # steady-state candidates asked so far: their job ids' numbers
    busy_seconds: float = 0.0  # workers' time on this run's episodes (simulate + encode)
    # Each candidate's episodes as they ran (who, the log's SHA-256, the scores), and the job ids
    # of those the referee has run again (analytic.evaluators.replication).
    provenance: dict[PDGains, tuple[Ran, ...]] = field(default_factory=dict)
    validated: set[str] = field(default_factory=set)
    # How each validated episode was checked: job id -> (Check, Ruling, the worker that ran it).
    checks: dict[str, tuple[str, str, str]] = field(default_factory=dict)
    ledger: Ledger = field(default_factory=Ledger)  # what validation cost and found
    # The key of the spot checks' draw: never leaves this process, so no worker can tell which
    # of its episodes will be checked; kept, so a resumed run draws as it would have.
    spot_key: bytes = field(default_factory=lambda: secrets.token_bytes(16))
    # The spot checks' rate, fixed as the run first starts (RunConfig.spot_checks, or sized for
    # the farm it starts on) and kept, so a resumed run draws as it would have; and what it was
    # sized on: the episodes the run plans and the farm's workers then.
    spot_rate: float | None = None
    spot_plan: tuple[int, int] | None = None
    rewinds: int = 0  # times the evolution started again without a caught worker's results
    unchecked: str = ""  # why the front's episodes are not refereed (trusted, or switched off)
    lag_measured: bool = True  # `measured` holds the lag (False: a checkpoint from before it)

    def __setstate__(self, state: dict) -> None:
        """Checkpoints from before validation by a referee have nothing validated yet."""
        defaults = {
            "provenance": {},
            "validated": set(),
            "checks": {},
            "ledger": Ledger(),
            "spot_key": secrets.token_bytes(16),
            "spot_rate": None,
            "spot_plan": None,
            "rewinds": 0,
            "unchecked": "",
        }
        self.__dict__.update({**defaults, **state})
        if "measured" not in state:  # from before the limits: its points count as within them
            self.measured = [(0.0,) * len(MEASURES) for _ in self.evaluated]
        elif not state.get("lag_measured", False):  # from before the lag: its points had none
            self.measured = [before_lag(values) for values in self.measured]
        self.lag_measured = True


@dataclass(frozen=True)
class RunProgress:
    """Where a run stands, after each evaluation and once more as each generation ends (with
    `ended`; its records and checkpoint are written at most every RECORD_SECONDS, and as the run
    stops): for a progress line. `generation` counts the
    generations ended; `hypervolume` and `best_f_acc` are the last ended one's (NaN before)."""

    generation: int
    evaluations: int
    hypervolume: float
    best_f_acc: float
    elapsed: float
    ended: bool = False
    # The evaluations the run's budget allows (--evaluations, or --generations times the
    # population); None when it stops on convergence, whose moment cannot be known ahead.
    budget: int | None = None
    # For a run that stops on convergence, the evaluations at which it is expected to: a fit of
    # its hypervolume's course (termination.expected_generations); None without one.
    expected: int | None = None


class TuningRun:
    def __init__(
        self,
        directory: Path,
        config: RunConfig,
        state: RunState,
        identity: RunIdentity,
        lock: Lock,
    ):
        self.directory = Path(directory)
        self.config = config
        self.state = state
        self.identity = identity
        self._lock = lock
        self._said_alone: set[str] = set()  # caught workers with nobody to run their episodes
        self._records_due = -math.inf  # when a generation's end next writes the records
        self._expected: int | None = None  # evaluations, as RunProgress.expected
        # What the checkpoint on disk holds: a Ctrl-C says this, not the generation reached,
        # since the records are written at most every RECORD_SECONDS and a resume starts from
        # them. (Not written on the way out: mid-generation the optimiser has already been
        # asked for the next candidates, and keeping a copy of every ended generation's state
        # would cost the pickling RECORD_SECONDS saves.)
        self.saved_generations = len(state.history)
        self.saved_stopped = state.stopped is not None

    @classmethod
    def create(
        cls, directory: Path, config: RunConfig, feedforward: bytes | None = None
    ) -> "TuningRun":
        """A new run in `directory` (FileExistsError if it already holds one), holding its lock.
        `feedforward` is the model file the config names by its SHA-256, if it names one."""
        # model_copy(update=...) skips validation: check the whole config once more.
        config = RunConfig.model_validate(config.model_dump())
        given = digest(feedforward) if feedforward is not None else None
        if given != config.feedforward:
            raise ValueError(f"the feed-forward model given ({given}) is not the config's")
        evolution = _evolution(config)  # before any file: an algorithm that cannot run, no run
        directory = Path(directory)
        _refuse_existing(directory)
        directory.mkdir(parents=True, exist_ok=True)
        lock = _lock(directory)
        try:
            _refuse_existing(directory)  # again, holding the lock: two starts on one --out
            remove_leftovers(directory)
            identity = RunIdentity.new()
            # run.json first: config.json is what says a run is here.
            write_atomically(directory / RUN_JSON, run_json(identity))
            if feedforward is not None:
                write_atomically(directory / FEEDFORWARD, feedforward)
            write_atomically(directory / CONFIG_JSON, config.model_dump_json(indent=2).encode())
        except BaseException:
            lock.release()
            raise
        return cls(directory, config, RunState(evolution), identity, lock)

    @classmethod
    def open(cls, directory: Path) -> "TuningRun":
        """The run in `directory`, as its last checkpoint left it, holding its lock.
        CheckpointRefused if the checkpoint is not this run's own."""
        directory = Path(directory)
        config = RunConfig.model_validate_json(
            read_bounded(directory / CONFIG_JSON, MAX_RECORD_BYTES)
        )
        lock = _lock(directory)
        try:
            remove_leftovers(directory)
            identity = _identity(directory)
            checkpoint = directory / CHECKPOINT
            if checkpoint.exists():
                raw = read_bounded(checkpoint, MAX_CHECKPOINT_BYTES)
                state = decode(raw, checkpoint, identity, config.algorithm)
                if not (isinstance(state, RunState) and isinstance(state.evolution, Evolution)):
                    raise CheckpointRefused(f"{checkpoint}: not a gainfarm checkpoint (no run)")
                state.evolution.constrain(config.limits.count)  # from before the limits: none yet
            else:  # stopped before its first generation ended
                state = RunState(_evolution(config))
        except BaseException:
            lock.release()
            raise
        return cls(directory, config, state, identity, lock)

    def close(self) -> None:
        """Release the run's lock: another process may open it now, and this object only
        reads (its state and front stay as they were)."""
        self._lock.release()

    def __enter__(self) -> "TuningRun":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def check_open(self) -> None:
        """RuntimeError unless this object holds the run's lock, which writing needs."""
        if not self._lock.held:
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

    @property
    def finished(self) -> bool:
        return self.state.stopped is not None

    @property
    def replication(self) -> Ledger:
        """What validation cost and found over the run (every process that ran it)."""
        return self.state.ledger

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

    def front(self) -> list[FrontMember]:
        """The best front found so far, most accurate first, each member with its kept logs."""
        return sorted_front(_rows(self.state, self.config.objectives))

    def run(
        self,
        evaluator: Evaluator,
        on_progress: Callable[[RunProgress], None] = lambda _: None,
        *,
        referee: Evaluator | None = None,
    ) -> str:
        """Evolve until the termination says stop, validate the front if the config says so, and
        return why it stopped. `referee` runs episodes again to check the workers' (a share of
        them as they return, and the front's before it is reported; by default this process:
        analytic.evaluators.replication). A worker it catches lying is distrusted, and a
        generational run starts its evolution again from the seed without that worker's results
        (`rewinds`): episodes are deterministic, so every other result is taken as it was, and
        the run retraces the one an honest farm would have run.
        The records are written as it goes; the figures and report.md are drawn by what
        composes the run (analytic.view.run_report)."""
        self.check_open()
        started = time.monotonic() - self.state.wall_seconds
        referee = self._referee(evaluator, referee)
        if referee is not None and self.state.spot_rate is None:
            self._size_spot_checks(evaluator)
        while True:
            while self.state.stopped is None:
                if self.config.asynchronous and self.state.evolution.generation > 0:
                    self._steady_state(evaluator, started, on_progress, referee)
                else:
                    self._generation(evaluator, started, on_progress, referee)
            if referee is None or not self._validate_front(evaluator, referee):
                return self.state.stopped

    def _referee(self, evaluator: Evaluator, referee: Evaluator | None) -> Evaluator | None:
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
        return referee or InProcessEvaluator(self.directory, models=self.models())

    def referee_for(self, evaluator: Evaluator) -> Evaluator | None:
        """The referee of `evaluator`'s episodes (this process), or None when none is needed
        (the config's replicate is off, or `evaluator` is trusted): for the held-out check."""
        return self._referee(evaluator, None)

    def planned_episodes(self) -> int:
        """The episodes the run plans: its budget of evaluations (for a run that stops on
        convergence, the fewest it can: the termination's window and one generation more),
        each an episode per trajectory and plant."""
        config = self.config
        evaluations = config.budget or (config.termination.window + 1) * config.pop
        return evaluations * len(config.trajectories) * (1 + len(config.plants))

    def _size_spot_checks(self, evaluator: Evaluator) -> None:
        """Fix the spot checks' rate as the run first starts: the config's, or sized so that a
        worker doing its share of the planned episodes (over the farm's workers now) and lying
        on a tenth of them is caught with probability 0.99 (replication.sized_rate). A run that
        converges later than it could only checks more lies at that rate."""
        planned, workers = self.planned_episodes(), max(1, evaluator.capacity)
        self.state.spot_plan = (planned, workers)
        if self.config.spot_checks is None:
            self.state.spot_rate = sized_rate(planned / workers)
        else:
            self.state.spot_rate = self.config.spot_checks

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

    def baseline(self, evaluator: Evaluator | None = None) -> Baseline | None:
        """The default gains' point on the run's trajectories, scored as the candidates are: from
        baseline.json, or (given an evaluator) evaluated now, one job per trajectory, and kept
        there. Episodes are deterministic, so once is enough. None if there is none yet."""
        path = self.directory / BASELINE_JSON
        if path.exists():
            try:
                kept = read_baseline(path)
            except ValueError:
                kept = None
            if kept is not None and kept.gains == DEFAULT_GAINS:
                return kept
        if evaluator is None:
            return None
        jobs = self._job_ids("baseline")
        specs = {job_id: self._episode_spec(DEFAULT_GAINS, job_id) for job_id in jobs}
        evaluator.submit(specs)
        found = {evaluation.job_id: evaluation for evaluation in evaluator.results()}
        rulings = self._referee_baseline(evaluator, found)
        self.replay_without_caught(evaluator)
        scores = [found[job_id].scores if job_id in found else None for job_id in jobs]
        baseline = Baseline(
            gains=DEFAULT_GAINS,
            objectives=self._objectives(scores),
            names=self.config.objectives,
            maximised=maximised(self.config.objectives),
            diverged=any(s is None or s.diverged for s in scores),
            episodes=tuple(
                {
                    "job_id": job_id,
                    "status": found[job_id].status.value if job_id in found else "lost",
                    "reason": found[job_id].reason if job_id in found else "no result",
                    "scores": s.model_dump() if s is not None else None,
                    "worker": found[job_id].worker if job_id in found else "",
                    "check": rulings.get(job_id, self.state.unchecked or "not checked"),
                }
                for job_id, s in zip(jobs, scores, strict=True)
            ),
        )
        write_atomically(path, baseline_json(baseline))
        if rulings:  # the ledger's baseline count, in the records and the checkpoint
            with interrupts_deferred():
                self.write_records()
                self._checkpoint()
        return baseline

    def replay_without_caught(self, evaluator: Evaluator) -> bool:
        """After the evolution, a worker caught lying (on the default gains' episodes, or the
        held-out check's) may have steered it: a generational run starts it again from the seed
        without that worker's results and runs it to its end (True), as a catch during the
        evolution does."""
        if not self._should_rewind(evaluator):
            return False
        self._rewind(evaluator)
        self.run(evaluator)
        return True

    def _referee_baseline(
        self, evaluator: Evaluator, found: dict[str, EpisodeResult]
    ) -> dict[str, str]:
        """On a farm not its own, the referee runs every episode of the default gains: report.md
        and the held-out check measure the front against them, so one forged episode would turn
        the advice. Each takes the referee's standing evaluation in `found` (its own where it
        contradicts the worker's); returns the rulings, by job id."""
        referee = self._referee(evaluator, None)
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
        for evaluation in evaluations:
            if evaluation.log is not None:
                evaluation.log.unlink(missing_ok=True)

    # --- generational: a whole generation out, then told in the order asked -------------------

    def _generation(
        self,
        evaluator: Evaluator,
        started: float,
        on_progress: Callable[[RunProgress], None],
        referee: Evaluator | None,
    ) -> None:
        evolution = self.state.evolution
        if self._nobody_left(evaluator):
            return
        candidates = evolution.ask()
        jobs = {
            gains: self._job_ids(f"{self._prefix()}g{evolution.generation:04d}-c{index:03d}")
            for index, gains in enumerate(candidates)
        }
        known = {gains for gains in candidates if self._known(gains, evaluator)}
        specs = self._specs({gains: ids for gains, ids in jobs.items() if gains not in known})
        results: dict[str, EpisodeResult] = {}
        if specs:
            evaluator.submit(specs)
        try:
            for evaluation in evaluator.results() if specs else ():
                results[evaluation.job_id] = evaluation
                self._account(evaluation)
                # As it arrives, while the farm runs the rest; and before anything is told, so
                # a lie caught now has steered nothing yet.
                caught = self._spot_check(evaluator, referee, results, evaluation.job_id)
                if caught and self._nobody_left(evaluator):  # the generation cannot finish
                    return
                on_progress(self._progress(len(results) // len(jobs[candidates[0]]), started))
        finally:  # stopped mid-generation (Ctrl-C): leave nothing queued in the evaluator
            evaluator.cancel([job_id for job_id in specs if job_id not in results])
        for gains in candidates:
            if gains not in known:
                self._record(gains, jobs[gains], results)
        if self._should_rewind(evaluator):
            self._rewind(evaluator)
            return
        done = [self._candidate_done(gains) for gains in candidates]
        evolution.tell([found for found, _ in done], [g for _, g in done])
        self._generation_done(started, evaluator)
        on_progress(self._progress(0, started, ended=True))
        if self._should_rewind(evaluator):  # a front member's fetched log gave its worker away
            self._rewind(evaluator)

    # --- starting again without a caught worker's results -------------------------------------

    def _prefix(self) -> str:
        """Job ids after a rewind are new ones: a log of the run before is never overwritten."""
        return f"r{self.state.rewinds}-" if self.state.rewinds else ""

    def job_prefix(self) -> str:
        """What the job ids of the run's episodes start with now (`_prefix`): for the held-out
        check's, which a rewind runs again."""
        return self._prefix()

    def _distrusted(self, evaluator: Evaluator) -> set[str]:
        return {*self.state.ledger.dissenters, *getattr(evaluator, "distrusted", ())}

    def _known(self, gains: PDGains, evaluator: Evaluator) -> bool:
        """Whether a candidate of a rewound run was evaluated before by workers still trusted:
        its episodes are deterministic, so they are not run again. (Before any rewind, a run
        evaluates whatever it is asked, as it always did.)"""
        if not self.state.rewinds or gains not in self.state.provenance:
            return False
        distrusted = self._distrusted(evaluator)
        return not any(ran.worker in distrusted for ran in self.state.provenance[gains])

    def _caught(self, evaluator: Evaluator) -> set[str]:
        """Distrusted workers whose results the run still holds."""
        ran = {ran.worker for episodes in self.state.provenance.values() for ran in episodes}
        return ran & self._distrusted(evaluator)

    @staticmethod
    def _trusted_left(evaluator: Evaluator, distrusted: set[str]) -> bool:
        """Whether a worker not distrusted is there to run episodes: by name where the
        evaluator knows them (FarmClient.trusted_capacity: a caught worker may have gone),
        else by count."""
        trusted = getattr(evaluator, "trusted_capacity", None)
        if trusted is not None:
            return trusted > 0
        return evaluator.capacity > len(distrusted)

    def _nobody_left(self, evaluator: Evaluator) -> bool:
        """Stop the run when every worker of the farm is distrusted: nobody is left to run its
        episodes (they would wait out every deadline)."""
        distrusted = self._distrusted(evaluator)
        if not distrusted or self._trusted_left(evaluator, distrusted):
            return False
        self.state.stopped = f"no trusted worker left ({', '.join(sorted(distrusted))} lied)"
        log.error("every worker of the farm is distrusted: the run stops")
        with interrupts_deferred():
            self.write_records()
            self._checkpoint()
        return True

    def _should_rewind(self, evaluator: Evaluator) -> bool:
        """Whether to start again without the caught workers' results: in a generational run
        (a steady state's order is the farm's: it would not retrace), with workers left to run
        their episodes again (else the referee's corrections of the front are all there is)."""
        caught = self._caught(evaluator)
        if not caught or self.config.asynchronous:
            return False
        if self._trusted_left(evaluator, self._distrusted(evaluator)):
            return True
        if caught - self._said_alone:  # once per worker, not every generation
            self._said_alone |= caught
            log.error(
                "%s lied about episodes and no other worker is left to run them again: only "
                "the front is corrected, by the referee",
                ", ".join(sorted(caught)),
            )
        return False

    def _rewind(self, evaluator: Evaluator) -> None:
        """Start the evolution again from its seed without the caught workers' results: what
        they ran is forgotten (and runs again, on the workers still trusted, when it is asked
        again); everything else is taken as it was. A generational run is deterministic given
        what it is told, so this retraces the run an honest farm would have made."""
        state = self.state
        caught = self._caught(evaluator)
        for gains, episodes in list(state.provenance.items()):
            if any(ran.worker in caught for ran in episodes):
                del state.provenance[gains]
                for job_id in state.episodes.pop(gains, []):
                    (self.directory / EPISODES / f"{job_id}.mcap").unlink(missing_ok=True)
        state.evolution = _evolution(self.config)
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
            self._checkpoint()

    def _spot_check(
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
        """`_spot_check`'s work for one kind of check: True if it caught a worker lying."""
        validation = validate(evaluator, drawn, self.state.ledger, referee=referee, check=check)
        self._note_checks(check, validation, {e.job_id: e.worker for e in drawn})
        for evaluation in drawn:
            job_id = evaluation.job_id
            if job_id in validation.standing:
                results[job_id] = validation.standing[job_id]
            else:  # unsettled: it fails, as a front member the referee cannot run does
                reason = "the referee could not run it again"
                results[job_id] = dataclasses.replace(
                    evaluation, status=EpisodeStatus.failed, scores=None, digest=None, reason=reason
                )
        return Ruling.contradicted in validation.rulings.values()

    def _note_checks(self, check: Check, validation: Validation, workers: dict[str, str]) -> None:
        self.state.validated.update(validation.rulings)
        for job_id, ruling in validation.rulings.items():
            self.state.checks[job_id] = (check.value, ruling.value, workers[job_id])

    # --- steady state: each candidate told as it returns, a new one asked at once -------------

    def _steady_state(
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
        in_flight: dict[str, tuple[Population, PDGains, list[str]]] = {}
        results: dict[str, EpisodeResult] = {}

        def launch() -> None:
            handle, gains = evolution.ask_one()
            self.state.serial += 1
            name = f"s{self.state.serial:06d}"
            in_flight[name] = (handle, gains, self._job_ids(name))
            evaluator.submit(self._specs({gains: in_flight[name][2]}))

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
            for evaluation in evaluator.results():
                name = evaluation.job_id.rsplit("-t", 1)[0]
                results[evaluation.job_id] = evaluation
                self._account(evaluation)
                handle, gains, ids = in_flight[name]
                if not all(job_id in results for job_id in ids):
                    continue
                del in_flight[name]
                caught = self._spot_check(evaluator, referee, results, *ids)
                if caught and self._nobody_left(evaluator):
                    return
                self._record(gains, ids, results)
                evolution.tell_one(handle, *self._candidate_done(gains))
                on_progress(self._progress(0, started))
                if evolution.evaluations % self.config.pop == 0 or evolution.evaluations >= budget:
                    self._generation_done(started, evaluator)
                    on_progress(self._progress(0, started, ended=True))
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

    # --- validation by replication -----------------------------------------------------------

    def _validate_front(self, evaluator: Evaluator, referee: Evaluator) -> bool:
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
                self._evaluation(gains, ran)
                for gains, episodes in todo.items()
                for ran in episodes
                if ran.job_id not in state.validated
            ]
            if not originals:
                break
            checked = True
            validation = validate(evaluator, originals, state.ledger, referee=referee)
            self._note_checks(Check.refereed, validation, {e.job_id: e.worker for e in originals})
            if self._should_rewind(evaluator):
                self._rewind(evaluator)
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
                    self._correct(gains, now)
                    self._drop_stale_logs(gains, now)
                self._keep_refereed(gains, [standing.get(r.job_id) for r in now])
        if self._fetch_front(evaluator):
            checked = corrected = True
            if self._should_rewind(evaluator):
                self._rewind(evaluator)
                return True
        if checked:
            if corrected and state.history:  # the last row says what the run reports
                state.history[-1] = self._row_of(state.evolution.front(), state.history[-1])
            with interrupts_deferred():  # the records and the checkpoint agree
                self.write_records()
                self._checkpoint()
        return False

    def _evaluation(self, gains: PDGains, ran: Ran) -> EpisodeResult:
        """An original as validation takes it: the episode's spec, who ran it, its log."""
        spec = self._episode_spec(gains, ran.job_id)
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

    # --- the front's logs, where workers keep them --------------------------------------------

    def _fetch_front(self, evaluator: Evaluator, simulate_again: bool = True) -> bool:
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
                        self._episode_spec(gains, job_id), ran.digest, (ran.worker,), ran.scores
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
                self._correct(gains, tuple(now))

    def _correct(self, gains: PDGains, standing: tuple[Ran, ...]) -> None:
        """A candidate's episodes as they truly ran, and the objectives they give, everywhere
        the run keeps them: evaluated.csv holds the points in the order told, so the true one
        replaces the false one there too, and the cloud and the front agree."""
        self.state.provenance[gains] = standing
        scores = [ran.scores for ran in standing]
        true = self._objectives(scores)
        measured = measures(scores)
        g = self.config.limits.constraints(measured)
        for row in self.state.evolution.correct(gains, true, g):
            self.state.evaluated[row] = true
            self.state.measured[row] = measured

    def _keep_refereed(self, gains: PDGains, standing: list[EpisodeResult | None]) -> None:
        """A member's logs validation left here (the referee's, where the worker's is not
        here) are kept, as fetched ones are: nothing to fetch."""
        kept = self.state.episodes.setdefault(gains, [])
        for evaluation in standing:
            if (
                evaluation is not None
                and evaluation.log is not None
                and evaluation.job_id not in kept
            ):
                kept.append(evaluation.job_id)

    def _drop_stale_logs(self, gains: PDGains, standing: tuple[Ran, ...]) -> None:
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

    def _episode_spec(self, gains: PDGains, job_id: str) -> EpisodeSpec:
        """The spec of a candidate's episode, from its job id (`_job_ids`)."""
        return self.config.episode_spec(gains, *slot_of(job_id))

    def _row_of(self, front: list[Candidate], row: HistoryRow) -> HistoryRow:
        """`row` with the hypervolume and bests of `front` (after a correction)."""
        points = [member.objectives for member in front]
        return dataclasses.replace(
            row,
            hypervolume=hypervolume(points, self.config.reference_point),
            best=best_of(points, self.config.objectives),
        )

    # --- bookkeeping -------------------------------------------------------------------------

    def _account(self, evaluation: EpisodeResult) -> None:
        if evaluation.timings is not None:
            timings = evaluation.timings
            self.state.busy_seconds += timings.simulate_s + timings.encode_s

    def _job_ids(self, candidate: str) -> list[str]:
        """A candidate's episodes: each trajectory on the nominal plant (`-t<n>`, as before there
        were variants), then on each plant variant (`-t<n>-p<k>`), the order `objectives` takes."""
        variants = len(self.config.plants)
        return [
            f"{candidate}-t{number}{f'-p{plant}' if plant else ''}"
            for number in range(len(self.config.trajectories))
            for plant in range(1 + variants)
        ]

    def _objectives(self, scores: Sequence[Scores | None]) -> tuple[float, float]:
        """A candidate's objectives from its episodes' scores, in `_job_ids`' order."""
        config = self.config
        return objectives(
            scores,
            config.objective_weights,
            1 + len(config.plants),
            config.aggregate,
            config.plant_scales,
            no_episode(declarations(config.objectives)),
        )

    def _specs(self, jobs: dict[PDGains, list[str]]) -> dict[str, EpisodeSpec]:
        return {
            job_id: self._episode_spec(gains, job_id)
            for gains, ids in jobs.items()
            for job_id in ids
        }

    def _progress(
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

    def _record(
        self, gains: PDGains, job_ids: list[str], results: dict[str, EpisodeResult]
    ) -> None:
        """A candidate's episodes as they ran, and the logs of them kept here."""
        self.state.episodes[gains] = [i for i in job_ids if results[i].log is not None]
        self.state.provenance[gains] = tuple(Ran.of(results[job_id]) for job_id in job_ids)

    def _candidate_done(self, gains: PDGains) -> tuple[tuple[float, float], tuple[float, ...]]:
        """A recorded candidate's objectives and constraint values (schemas.limits: its worst
        measures over all its episodes), with its point recorded as told."""
        scores = [ran.scores for ran in self.state.provenance[gains]]
        found = self._objectives(scores)
        measured = measures(scores)
        self.state.evaluated.append(found)
        self.state.measured.append(measured)
        return found, self.config.limits.constraints(measured)

    def _generation_done(self, started: float, evaluator: Evaluator) -> None:
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
        stopping = self._stops() is not None
        fetch = not trusted or due or stopping
        if fetch and self._fetch_front(evaluator, simulate_again=not trusted or stopping):
            front = state.evolution.front()  # a member's scores were false: the front moved
            state.history[-1] = self._row_of(front, state.history[-1])
        state.stopped = self._stops()
        # Fitted once a generation, not at every evaluation's progress line.
        expected = expected_generations(
            self.config.termination, [row.hypervolume for row in state.history]
        )
        self._expected = None if expected is None else expected * self.config.pop
        if state.stopped is None and not due:
            return
        # A Ctrl-C between history.csv and the checkpoint would leave them a generation apart.
        with interrupts_deferred():
            self.write_records()
            self._checkpoint()
        self._records_due = time.monotonic() + RECORD_SECONDS

    def _stops(self) -> str | None:
        """Why the run stops now (the termination's reason, from its history), or None."""
        hypervolumes = [row.hypervolume for row in self.state.history]
        return self.config.termination.reason(hypervolumes, self.state.evolution.evaluations)

    def _checkpoint(self) -> None:
        write_atomically(self.directory / CHECKPOINT, encode(self.state, self.identity))
        self.saved_generations = len(self.state.history)
        self.saved_stopped = self.state.stopped is not None

    def validation_pending(self) -> bool:
        """Whether a front member's episodes are still to be refereed: a run stopped (Ctrl-C)
        while its front was being validated, whose `run()` goes on with it."""
        if not self.config.replicate or self.state.unchecked:
            return False
        return any(
            ran.job_id not in self.state.validated
            for member in self.state.evolution.front()
            for ran in self.state.provenance.get(member.gains, ())
        )

    # --- the record --------------------------------------------------------------------------

    def write_records(self) -> None:
        """The plain files of where the run stands (analytic.records), history.csv last: a
        reader that finds a generation in history.csv finds its front and points too. (A crash
        between history.csv and the checkpoint leaves the plain files a generation ahead: a
        resume runs that generation again, to the same, deterministic, result.)"""
        self.check_open()
        names = self.config.objectives
        rows = _rows(self.state, names)
        write_atomically(
            self.directory / EVALUATED_CSV,
            evaluated_csv(
                self.state.evaluated, self.state.measured, self.config.limits, declarations(names)
            ),
        )
        write_atomically(self.directory / FRONT_JSON, front_json(rows, self.validation()))
        write_atomically(self.directory / PROVENANCE_CSV, provenance_csv(rows))
        write_atomically(self.directory / FRONT_CSV, front_csv(rows, names))
        write_atomically(self.directory / HISTORY_CSV, history_csv(self.state.history, names))


def _evolution(config: RunConfig) -> Evolution:
    return Evolution(
        config.pop,
        config.seed,
        steady_state=config.asynchronous,
        algorithm=config.algorithm,
        objective_scaling=config.objective_scaling,
        reference=config.reference_point,
        constraints=config.limits.count,
        from_defaults=config.from_defaults,
    )


def _rows(state: RunState, names: tuple[str, ...]) -> list[FrontMember]:
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


def slot_of(job_id: str) -> tuple[int, int]:
    """(trajectory, plant) of a candidate's job id: `<candidate>-t<n>[-p<k>]`."""
    number, _, plant = job_id.rsplit("-t", 1)[1].partition("-p")
    return int(number), int(plant or 0)


def _refuse_existing(directory: Path) -> None:
    if (directory / CONFIG_JSON).exists():
        raise FileExistsError(f"{directory} already holds a run; resume it or choose another")


def _lock(directory: Path) -> Lock:
    try:
        return Lock(directory / LOCK)
    except Locked as locked:
        raise RunBusy(directory, locked.holder) from None


def _identity(directory: Path) -> RunIdentity:
    """The run's identity from run.json. A run from before run ids gets one now, which pins the
    id-less checkpoint it has (analytic.checkpoint): one atomic write, so a kill cannot leave
    the run half-upgraded."""
    if (directory / RUN_JSON).exists():
        return read_identity(directory / RUN_JSON)
    checkpoint = directory / CHECKPOINT
    legacy = hashlib.sha256(checkpoint.read_bytes()).hexdigest() if checkpoint.exists() else None
    identity = RunIdentity.new(legacy)
    write_atomically(directory / RUN_JSON, run_json(identity))
    return identity


def upgrade(directory: Path) -> None:
    """Give a run written before front.json and evaluated.csv existed those files, from its
    checkpoint, so that it reads like any other (analytic.records.read_run); opening it gives it
    a run id too. A run that needs nothing is not opened (nor locked, nor written: a reader of
    an archive of runs may have no write access). One that another process is running is left
    to it: that process writes the records."""
    directory = Path(directory)
    if (directory / CHECKPOINT).exists() and not (directory / FRONT_JSON).exists():
        try:
            run = TuningRun.open(directory)
        except RunBusy:
            return
        with run:
            run.write_records()
