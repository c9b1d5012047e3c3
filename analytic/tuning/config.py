"""A tuning run's configuration: everything that decides its outcome, validated as a whole."""

from typing import Annotated, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator

from gainfarm.analytic.tuning.evolution import (
    REFERENCE_POINT,
    STEADY_STATE_ONLY,
    Algorithm,
    ObjectiveScaling,
    steady_state_refusal,
)
from gainfarm.analytic.tuning.termination import (
    CONVERGENCE_TOLERANCE,
    CONVERGENCE_WINDOW,
    Termination,
)
from gainfarm.schemas.robot import ModelSpec
from gainfarm.schemas.trajectory import TrajectorySpec

PositiveFinite = Annotated[float, Field(gt=0, allow_inf_nan=False)]


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
    algorithm: Algorithm = Field(
        "nsga2",
        description="the optimiser (analytic.evolution.ALGORITHMS): pymoo's NSGA-II, NSGA-III, "
        "SMS-EMOA, MOEA/D or AGE-MOEA-II, Optuna's TPE, or uniform random sampling",
    )
    objective_scaling: ObjectiveScaling = Field(
        "raw",
        description="what the optimiser is told: the raw objectives, or (log) the normalised "
        "ones the hypervolume is taken on, f_t on a log scale; the records stay raw either way",
    )
    objective_weights: tuple[tuple[PositiveFinite, PositiveFinite], ...] | None = Field(
        None,
        description="a generic controller's objectives are the means over its trajectories, "
        "weighted per trajectory by these (f_acc weight, f_t weight) pairs, in the order of "
        "`trajectories` (schemas.objectives.balancing_weights: each trajectory counts alike at "
        "the default gains); None: the plain means",
    )
    keep: Literal["all", "front"] = "all"
    feedforward: str | None = Field(
        None,
        pattern=r"^[0-9a-f]{64}$",
        description="SHA-256 of the learned inverse-dynamics model every episode adds to its PD "
        "(the gains are tuned on top); the run directory keeps the file as feedforward.npz",
    )
    replicate: bool = Field(
        True,
        description="on a farm of 2+ workers, another worker reruns each front entrant's "
        "episodes and the logs must agree bit for bit (analytic/replication.py)",
    )

    @model_validator(mode="after")
    def _one_termination(self) -> Self:
        if self.generations is not None and self.evaluations is not None:
            raise ValueError("generations and evaluations exclude each other")
        if self.asynchronous and self.algorithm != STEADY_STATE_ONLY:
            raise ValueError(steady_state_refusal(self.algorithm))
        weights = self.objective_weights
        if weights is not None and len(weights) != len(self.trajectories):
            raise ValueError(
                f"objective_weights: {len(weights)} pairs for {len(self.trajectories)} "
                "trajectories (one pair per trajectory)"
            )
        return self

    @property
    def termination(self) -> Termination:
        return Termination(self.generations, self.evaluations, self.tolerance, self.window)

    @property
    def termination_text(self) -> str:
        if self.generations:
            return f"{self.generations} generations"
        if self.evaluations:
            return f"{self.evaluations} evaluations"
        return f"until converged ({self.termination.rule})"

    @property
    def mode(self) -> str:
        return "specific" if len(self.trajectories) == 1 else "generic"
