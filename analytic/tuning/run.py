"""A tuning run: NSGA-II generations evaluated by an evaluator, recorded in a run directory.

Optuna's Study, in its shape: the evolution step (analytic.tuning.evolution) is the sampler, an
evaluator (analytic.evaluators: the farm, or this process) runs the episodes, and the run
directory is the storage. TuningRun creates, opens and locks a run and composes its parts, each a
module of its own over one RunState (analytic.tuning.state): the loop's variants
(analytic.tuning.generational, analytic.tuning.steady_state), the rewinds after a caught worker
(analytic.tuning.rewinds), the referee's duties (analytic.tuning.referee), the front's episodes
(analytic.tuning.front) and the books (analytic.tuning.books). As a generation ends the run
writes, each file atomically (analytic.tuning.records), unless it wrote them less than
RECORD_SECONDS ago (and always as it stops):

    config.json      everything needed to repeat the run (written once)
    run.json         the run's id (written once), which its checkpoint carries
    run.lock         held by the one process writing the run
    checkpoint.pkl   the evolution with its random state, for resuming only (tuning.checkpoint)
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

import hashlib
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Evaluator
from gainfarm.analytic.evaluators.replication import Ledger
from gainfarm.analytic.tuning.books import CHECKPOINT, RECORD_SECONDS, Books, front_rows
from gainfarm.analytic.tuning.checkpoint import CheckpointRefused, decode
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import maximised
from gainfarm.analytic.tuning.evolution import Evolution
from gainfarm.analytic.tuning.front import FrontEpisodes
from gainfarm.analytic.tuning.generational import Generational
from gainfarm.analytic.tuning.jobs import candidate_objectives, episode_spec, job_ids, slot_of
from gainfarm.analytic.tuning.jobs import planned_episodes as planned
from gainfarm.analytic.tuning.records import (
    BASELINE_JSON,
    CONFIG_JSON,
    FEEDFORWARD,
    FRONT_JSON,
    LOCK,
    MAX_RECORD_BYTES,
    RUN_JSON,
    Baseline,
    FrontMember,
    RunIdentity,
    ValidationRecord,
    baseline_json,
    read_baseline,
    read_identity,
    run_json,
    sorted_front,
)
from gainfarm.analytic.tuning.referee import Refereeing
from gainfarm.analytic.tuning.rewinds import Rewinds
from gainfarm.analytic.tuning.state import RunProgress, RunState, evolution_of
from gainfarm.analytic.tuning.steady_state import SteadyState
from gainfarm.edges.files import Lock, Locked, remove_leftovers, write_atomically
from gainfarm.models.dynamics import digest
from gainfarm.schemas.documents import read_bounded

# Where they were before the run's parts had modules of their own, and are imported from still.
__all__ = [
    "CHECKPOINT",
    "RECORD_SECONDS",
    "RunBusy",
    "RunProgress",
    "RunState",
    "TuningRun",
    "slot_of",
    "upgrade",
]

# Read back within this: a population's whole state is some MB, a long TPE history tens.
MAX_CHECKPOINT_BYTES = 1 << 30


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


class TuningRun:
    """A tuning run in its directory, composed of its parts over one RunState: the books
    (analytic.tuning.books: each candidate, each generation's end, the records and checkpoint),
    the front's episodes (analytic.tuning.front), the rewinds (analytic.tuning.rewinds), the
    referee's duties (analytic.tuning.referee), and the loop's two variants
    (analytic.tuning.generational, analytic.tuning.steady_state)."""

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
        front = FrontEpisodes(self.directory, config, state)
        self._books = Books(self.directory, config, state, identity, lock, front)
        self._rewinds = Rewinds(self.directory, config, state, self._books)
        self._refereeing = Refereeing(
            self.directory, config, state, self._books, front, self._rewinds
        )
        parts = (config, state, self._books, self._rewinds, self._refereeing)
        self._generational = Generational(*parts)
        self._steady_state = SteadyState(*parts)

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
        evolution = evolution_of(config)  # before any file: an algorithm that cannot run, no run
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
                state = RunState(evolution_of(config))
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
        self._books.check_open()

    def models(self) -> dict[str, bytes]:
        """The feed-forward model the run's episodes use, by SHA-256, to serve to the workers
        (ValueError if the run directory's copy is missing or not the one the config names)."""
        return self._books.models()

    @property
    def saved_generations(self) -> int:
        """The generations the checkpoint on disk holds: a Ctrl-C says this, not the generation
        reached (the records are written at most every RECORD_SECONDS)."""
        return self._books.saved_generations

    @property
    def saved_stopped(self) -> bool:
        """Whether the checkpoint on disk holds the run stopped."""
        return self._books.saved_stopped

    @property
    def finished(self) -> bool:
        return self.state.stopped is not None

    @property
    def replication(self) -> Ledger:
        """What validation cost and found over the run (every process that ran it)."""
        return self.state.ledger

    def validation(self) -> ValidationRecord:
        """What validation found over the run, as its records say it."""
        return self._books.validation()

    def front(self) -> list[FrontMember]:
        """The best front found so far, most accurate first, each member with its kept logs."""
        return sorted_front(front_rows(self.state, self.config.objectives))

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
        referee = self._refereeing.referee(evaluator, referee)
        if referee is not None and self.state.spot_rate is None:
            self._refereeing.size_spot_checks(evaluator)
        while True:
            while self.state.stopped is None:
                if self.config.asynchronous and self.state.evolution.generation > 0:
                    self._steady_state.step(evaluator, started, on_progress, referee)
                else:
                    self._generational.step(evaluator, started, on_progress, referee)
            if referee is None or not self._refereeing.validate_front(evaluator, referee):
                return self.state.stopped

    def referee_for(self, evaluator: Evaluator) -> Evaluator | None:
        """The referee of `evaluator`'s episodes (this process), or None when none is needed
        (the config's replicate is off, or `evaluator` is trusted): for the held-out check."""
        return self._refereeing.referee(evaluator, None)

    def planned_episodes(self) -> int:
        """The episodes the run plans (analytic.tuning.jobs.planned_episodes)."""
        return planned(self.config)

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
            if kept is not None and kept.gains == self.config.default_gains:
                return kept
        if evaluator is None:
            return None
        jobs = job_ids(self.config, "baseline")
        defaults = self.config.default_gains
        specs = {job_id: episode_spec(self.config, defaults, job_id) for job_id in jobs}
        evaluator.submit(specs)
        found = {result.job_id: result for result in evaluator.results()}
        rulings = self._refereeing.referee_baseline(evaluator, found)
        self.replay_without_caught(evaluator)
        scores = [found[job_id].scores if job_id in found else None for job_id in jobs]
        baseline = Baseline(
            gains=defaults,
            objectives=candidate_objectives(self.config, scores),
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
            self._books.save()
        return baseline

    def replay_without_caught(self, evaluator: Evaluator) -> bool:
        """After the evolution, a worker caught lying (on the default gains' episodes, or the
        held-out check's) may have steered it: a generational run starts it again from the seed
        without that worker's results and runs it to its end (True), as a catch during the
        evolution does."""
        if not self._rewinds.due(evaluator):
            return False
        self._rewinds.rewind(evaluator)
        self.run(evaluator)
        return True

    def drop_refereed_logs(self, evaluations: Iterable[EpisodeResult]) -> None:
        """With --keep front, the logs the referee made of episodes no front member has go once
        ruled on (analytic.tuning.referee)."""
        self._refereeing.drop_refereed_logs(evaluations)

    def job_prefix(self) -> str:
        """What the job ids of the run's episodes start with now (`r<n>-` after a rewind): for
        the held-out check's, which a rewind runs again."""
        return self._rewinds.prefix()

    def validation_pending(self) -> bool:
        """Whether a front member's episodes are still to be refereed: a run stopped (Ctrl-C)
        while its front was being validated, whose `run()` goes on with it."""
        return self._refereeing.pending()

    def write_records(self) -> None:
        """The plain files of where the run stands (analytic.tuning.books.Books.write_records)."""
        self._books.write_records()


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
