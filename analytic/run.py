"""A tuning run: NSGA-II generations evaluated on the farm, recorded in a run directory.

The Study of this package, in Optuna's sense: the evolution step (analytic.evolution) is the
sampler, the farm evaluates, and the run directory is the storage. After every generation the
run writes, each file atomically:

    config.json      everything needed to repeat the run (written once)
    checkpoint.pkl   the evolution with its random state, the history, the evaluated points
    history.csv      one row per generation: evaluations, hypervolume, best f_acc and f_t, wall s
    front.csv        the non-dominated gains and their objectives
    episodes/        the MCAP logs (all, or only the front's with keep="front")

and at the end pareto.png, hypervolume.png and report.md. A stopped run continues from its last
checkpoint; the interrupted generation runs again, with the same candidates and the same
(deterministic) episodes, so the front is the one an uninterrupted run finds.
"""

import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field
from pymoo.core.population import Population

from analytic.evolution import REFERENCE_POINT, Candidate, Evolution, hypervolume, objectives
from analytic.farm import Evaluation, FarmClient
from analytic.figures import (
    FrontMember,
    HistoryRow,
    front_csv,
    history_csv,
    plot_hypervolume,
    plot_pareto,
    write_report,
)
from analytic.termination import CONVERGENCE_TOLERANCE, CONVERGENCE_WINDOW, Termination
from schemas.episode import EpisodeSpec
from schemas.files import write_atomically
from schemas.gains import PDGains
from schemas.robot import ModelSpec
from schemas.trajectory import TrajectorySpec

CONFIG = "config.json"
CHECKPOINT = "checkpoint.pkl"


class RunConfig(BaseModel):
    """Everything that decides a run's outcome (plus how to keep its episodes)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pop: int = Field(30, ge=4, le=1000, description="population size")
    seed: int = Field(0, ge=0)
    trajectories: tuple[TrajectorySpec, ...] = Field((TrajectorySpec(),), min_length=1)
    model: ModelSpec = ModelSpec()
    generations: int | None = Field(None, ge=1)
    evaluations: int | None = Field(None, ge=1)
    tolerance: float = Field(CONVERGENCE_TOLERANCE, gt=0)
    window: int = Field(CONVERGENCE_WINDOW, ge=1)
    reference_point: tuple[float, float] = REFERENCE_POINT
    asynchronous: bool = Field(False, description="steady-state NSGA-II, not generational")
    keep: Literal["all", "front"] = "all"

    @property
    def termination(self) -> Termination:
        return Termination(self.generations, self.evaluations, self.tolerance, self.window)

    @property
    def termination_text(self) -> str:
        if self.generations:
            return f"{self.generations} generations"
        if self.evaluations:
            return f"{self.evaluations} evaluations"
        return f"until converged (< {self.tolerance:.1%} over {self.window} generations)"

    @property
    def mode(self) -> str:
        return "specific" if len(self.trajectories) == 1 else "generic"


@dataclass
class RunState:
    """What a checkpoint holds: enough to continue exactly where the run stood."""

    evolution: Evolution
    history: list[HistoryRow] = field(default_factory=list)
    evaluated: list[tuple[float, float]] = field(default_factory=list)
    episodes: dict[PDGains, list[str]] = field(default_factory=dict)  # kept logs per candidate
    wall_seconds: float = 0.0
    stopped: str | None = None
    serial: int = 0  # steady-state candidates asked so far: their job ids' numbers
    busy_seconds: float = 0.0  # workers' time on this run's episodes (simulate + encode)


@dataclass(frozen=True)
class Progress:
    generation: int
    evaluations: int
    hypervolume: float
    best_f_acc: float
    elapsed: float


class TuningRun:
    def __init__(self, directory: Path, config: RunConfig, state: RunState):
        self.directory = Path(directory)
        self.config = config
        self.state = state

    @classmethod
    def create(cls, directory: Path, config: RunConfig) -> "TuningRun":
        """A new run in `directory` (FileExistsError if it already holds one)."""
        directory = Path(directory)
        if (directory / CONFIG).exists():
            raise FileExistsError(f"{directory} already holds a run; resume it or choose another")
        directory.mkdir(parents=True, exist_ok=True)
        write_atomically(directory / CONFIG, config.model_dump_json(indent=2).encode())
        return cls(directory, config, RunState(_evolution(config)))

    @classmethod
    def open(cls, directory: Path) -> "TuningRun":
        """The run in `directory`, as its last checkpoint left it."""
        directory = Path(directory)
        config = RunConfig.model_validate_json((directory / CONFIG).read_bytes())
        checkpoint = directory / CHECKPOINT
        if checkpoint.exists():
            state = pickle.loads(checkpoint.read_bytes())
        else:  # stopped before its first generation ended
            state = RunState(_evolution(config))
        return cls(directory, config, state)

    @property
    def finished(self) -> bool:
        return self.state.stopped is not None

    def run(
        self, farm: FarmClient, on_progress: Callable[[Progress], None] = lambda _: None
    ) -> str:
        """Evolve until the termination says stop; return why it stopped."""
        started = time.monotonic() - self.state.wall_seconds
        while self.state.stopped is None:
            if self.config.asynchronous and self.state.evolution.generation > 0:
                self._steady_state(farm, started, on_progress)
            else:
                self._generation(farm, started, on_progress)
        self.write_figures()
        return self.state.stopped

    # --- generational: a whole generation out, then told in the order asked -------------------

    def _generation(
        self, farm: FarmClient, started: float, on_progress: Callable[[Progress], None]
    ) -> None:
        evolution = self.state.evolution
        candidates = evolution.ask()
        jobs = {
            gains: self._job_ids(f"g{evolution.generation:04d}-c{index:03d}")
            for index, gains in enumerate(candidates)
        }
        farm.submit(self._specs(jobs))
        results: dict[str, Evaluation] = {}
        for evaluation in farm.results():
            results[evaluation.job_id] = evaluation
            self._account(evaluation)
            on_progress(self._progress(len(results) // len(self.config.trajectories), started))
        found = [self._candidate_done(gains, jobs[gains], results) for gains in candidates]
        evolution.tell(found)
        self._generation_done(started)

    # --- steady state: each candidate told as it returns, a new one asked at once -------------

    def _steady_state(
        self, farm: FarmClient, started: float, on_progress: Callable[[Progress], None]
    ) -> None:
        """Keep a few candidates per worker in flight so that none waits; a "generation" here is
        every `pop` evaluations, for the history, the termination and the checkpoint."""
        evolution = self.state.evolution
        in_flight: dict[str, tuple[Population, PDGains, list[str]]] = {}
        results: dict[str, Evaluation] = {}

        def launch() -> None:
            handle, gains = evolution.ask_one()
            self.state.serial += 1
            name = f"s{self.state.serial:06d}"
            in_flight[name] = (handle, gains, self._job_ids(name))
            farm.submit(self._specs({gains: in_flight[name][2]}))

        for _ in range(max(2, 2 * len(farm.status().workers))):
            launch()
        for evaluation in farm.results():
            results[evaluation.job_id] = evaluation
            self._account(evaluation)
            name = evaluation.job_id.rsplit("-t", 1)[0]
            handle, gains, ids = in_flight[name]
            if not all(job_id in results for job_id in ids):
                continue
            del in_flight[name]
            evolution.tell_one(handle, self._candidate_done(gains, ids, results))
            on_progress(self._progress(0, started))
            if evolution.evaluations % self.config.pop == 0:
                self._generation_done(started)
                if self.state.stopped is not None:
                    return  # what is still in flight is dropped with the study
            launch()

    # --- bookkeeping -------------------------------------------------------------------------

    def _account(self, evaluation: Evaluation) -> None:
        if evaluation.timings is not None:
            timings = evaluation.timings
            self.state.busy_seconds += timings.simulate_s + timings.encode_s

    def _job_ids(self, candidate: str) -> list[str]:
        return [f"{candidate}-t{number}" for number in range(len(self.config.trajectories))]

    def _specs(self, jobs: dict[PDGains, list[str]]) -> dict[str, EpisodeSpec]:
        return {
            job_id: EpisodeSpec(gains=gains, trajectory=trajectory, model=self.config.model)
            for gains, ids in jobs.items()
            for job_id, trajectory in zip(ids, self.config.trajectories, strict=True)
        }

    def _progress(self, evaluations_in_flight: int, started: float) -> Progress:
        best = self.state.history[-1] if self.state.history else None
        return Progress(
            generation=self.state.evolution.generation,
            evaluations=self.state.evolution.evaluations + evaluations_in_flight,
            hypervolume=best.hypervolume if best else 0.0,
            best_f_acc=best.best_f_acc if best else float("nan"),
            elapsed=time.monotonic() - started,
        )

    def _candidate_done(
        self, gains: PDGains, job_ids: list[str], results: dict[str, Evaluation]
    ) -> tuple[float, float]:
        """A candidate's objectives, with its episodes and point recorded."""
        found = objectives([results[job_id].scores for job_id in job_ids])
        self.state.evaluated.append(found)
        self.state.episodes[gains] = [i for i in job_ids if results[i].episode is not None]
        return found

    def _generation_done(self, started: float) -> None:
        """History row, front, pruned episodes, termination verdict and checkpoint."""
        state = self.state
        front = state.evolution.front()
        state.wall_seconds = time.monotonic() - started
        state.history.append(
            HistoryRow(
                generation=state.evolution.generation,
                evaluations=state.evolution.evaluations,
                hypervolume=hypervolume(
                    [member.objectives for member in front], self.config.reference_point
                ),
                best_f_acc=min(member.objectives[0] for member in front),
                best_f_t=min(member.objectives[1] for member in front),
                wall_seconds=state.wall_seconds,
            )
        )
        if self.config.keep == "front":
            keep = {member.gains for member in front}
            for gains in [gains for gains in state.episodes if gains not in keep]:
                for job_id in state.episodes.pop(gains):
                    (self.directory / "episodes" / f"{job_id}.mcap").unlink(missing_ok=True)
        write_atomically(self.directory / "front.csv", front_csv(_rows(front)))
        write_atomically(self.directory / "history.csv", history_csv(state.history))
        hypervolumes = [row.hypervolume for row in state.history]
        state.stopped = self.config.termination.reason(hypervolumes, state.evolution.evaluations)
        self._checkpoint()

    def _checkpoint(self) -> None:
        write_atomically(self.directory / CHECKPOINT, pickle.dumps(self.state))

    # --- the record --------------------------------------------------------------------------

    def write_figures(self) -> None:
        front = _rows(self.state.evolution.front())
        search = "steady-state" if self.config.asynchronous else "generational"
        title = (
            f"{self.config.mode} controller, {search} NSGA-II, "
            f"pop {self.config.pop}, seed {self.config.seed}"
        )
        plot_pareto(self.directory / "pareto.png", front, self.state.evaluated, title=title)
        plot_hypervolume(self.directory / "hypervolume.png", self.state.history, title=title)
        trajectories = ", ".join(
            f"{trajectory.kind.value} {trajectory.duration:g} s"
            for trajectory in self.config.trajectories
        )
        write_report(
            self.directory / "report.md",
            title=f"gainfarm run {self.directory.name}",
            config_lines=[
                f"{self.config.mode} controller on {trajectories}",
                f"{search} NSGA-II, population {self.config.pop}, seed {self.config.seed}",
                f"{self.config.model.joints} joints; reference point "
                f"f_acc {self.config.reference_point[0]} m, f_t {self.config.reference_point[1]}",
            ],
            history=self.state.history,
            front=front,
            converged=self.state.stopped or "stopped before it ended",
        )


def _evolution(config: RunConfig) -> Evolution:
    return Evolution(config.pop, config.seed, steady_state=config.asynchronous)


def _rows(front: list[Candidate]) -> list[FrontMember]:
    """The front as front.csv and the figures show it."""
    return [FrontMember(member.gains.kp, member.gains.kd, *member.objectives) for member in front]
