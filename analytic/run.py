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

from analytic.evolution import REFERENCE_POINT, Evolution, hypervolume, objectives
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
    keep: Literal["all", "front"] = "all"

    @property
    def termination(self) -> Termination:
        return Termination(self.generations, self.evaluations, self.tolerance, self.window)

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
        return cls(directory, config, RunState(Evolution(config.pop, config.seed)))

    @classmethod
    def open(cls, directory: Path) -> "TuningRun":
        """The run in `directory`, as its last checkpoint left it."""
        directory = Path(directory)
        config = RunConfig.model_validate_json((directory / CONFIG).read_bytes())
        checkpoint = directory / CHECKPOINT
        if checkpoint.exists():
            state = pickle.loads(checkpoint.read_bytes())
        else:  # stopped before its first generation ended
            state = RunState(Evolution(config.pop, config.seed))
        return cls(directory, config, state)

    @property
    def finished(self) -> bool:
        return self.state.stopped is not None

    def run(
        self, farm: FarmClient, on_progress: Callable[[Progress], None] = lambda _: None
    ) -> str:
        """Evolve until the termination says stop; return why it stopped."""
        termination = self.config.termination
        started = time.monotonic() - self.state.wall_seconds
        while self.state.stopped is None:
            evolution = self.state.evolution
            candidates = evolution.ask()
            jobs = self._jobs(evolution.generation, candidates)
            results = self._evaluate(farm, jobs, candidates, started, on_progress)
            evolution.tell(
                [objectives([results[job_id].scores for job_id in ids]) for ids in jobs.values()]
            )
            self._record(candidates, jobs, results, time.monotonic() - started)
            hypervolumes = [row.hypervolume for row in self.state.history]
            self.state.stopped = termination.reason(hypervolumes, evolution.evaluations)
            self._checkpoint()
        self.write_figures()
        return self.state.stopped

    # --- one generation ----------------------------------------------------------------------

    def _jobs(self, generation: int, candidates: list[PDGains]) -> dict[PDGains, list[str]]:
        return {
            gains: [
                f"g{generation:04d}-c{index:03d}-t{number}"
                for number in range(len(self.config.trajectories))
            ]
            for index, gains in enumerate(candidates)
        }

    def _evaluate(
        self,
        farm: FarmClient,
        jobs: dict[PDGains, list[str]],
        candidates: list[PDGains],
        started: float,
        on_progress: Callable[[Progress], None],
    ) -> dict[str, Evaluation]:
        specs = {
            job_id: EpisodeSpec(gains=gains, trajectory=trajectory, model=self.config.model)
            for gains in candidates
            for job_id, trajectory in zip(jobs[gains], self.config.trajectories, strict=True)
        }
        farm.submit(specs)
        results: dict[str, Evaluation] = {}
        done_before = self.state.evolution.evaluations
        best = self.state.history[-1] if self.state.history else None
        for evaluation in farm.results():
            results[evaluation.job_id] = evaluation
            on_progress(
                Progress(
                    generation=self.state.evolution.generation,
                    evaluations=done_before + len(results) // len(self.config.trajectories),
                    hypervolume=best.hypervolume if best else 0.0,
                    best_f_acc=best.best_f_acc if best else float("nan"),
                    elapsed=time.monotonic() - started,
                )
            )
        return results

    def _record(
        self,
        candidates: list[PDGains],
        jobs: dict[PDGains, list[str]],
        results: dict[str, Evaluation],
        wall_seconds: float,
    ) -> None:
        state = self.state
        for gains in candidates:
            state.evaluated.append(objectives([results[i].scores for i in jobs[gains]]))
            state.episodes[gains] = [i for i in jobs[gains] if results[i].episode is not None]
        front = state.evolution.front()
        state.history.append(
            HistoryRow(
                generation=state.evolution.generation,
                evaluations=state.evolution.evaluations,
                hypervolume=hypervolume(
                    [member.objectives for member in front], self.config.reference_point
                ),
                best_f_acc=min(member.objectives[0] for member in front),
                best_f_t=min(member.objectives[1] for member in front),
                wall_seconds=wall_seconds,
            )
        )
        state.wall_seconds = wall_seconds
        if self.config.keep == "front":
            keep = {member.gains for member in front}
            for gains in [gains for gains in state.episodes if gains not in keep]:
                for job_id in state.episodes.pop(gains):
                    (self.directory / "episodes" / f"{job_id}.mcap").unlink(missing_ok=True)
        members = [
            FrontMember(member.gains.kp, member.gains.kd, *member.objectives) for member in front
        ]
        write_atomically(self.directory / "front.csv", front_csv(members))
        write_atomically(self.directory / "history.csv", history_csv(state.history))

    def _checkpoint(self) -> None:
        write_atomically(self.directory / CHECKPOINT, pickle.dumps(self.state))

    # --- the record --------------------------------------------------------------------------

    def write_figures(self) -> None:
        front = [
            FrontMember(member.gains.kp, member.gains.kd, *member.objectives)
            for member in self.state.evolution.front()
        ]
        title = f"{self.config.mode} controller, pop {self.config.pop}, seed {self.config.seed}"
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
                f"NSGA-II, population {self.config.pop}, seed {self.config.seed}",
                f"{self.config.model.joints} joints; reference point "
                f"f_acc {self.config.reference_point[0]} m, f_t {self.config.reference_point[1]}",
            ],
            history=self.state.history,
            front=front,
            converged=self.state.stopped or "stopped before it ended",
        )
