"""A tuning run's configuration: everything that decides its outcome, validated as a whole.

A run tunes one robot, the one its plant names (`plant.robot`): its variants are of the same
robot, its default trajectory is centred on the robot's workspace centre when none is given, and
the gains it is handed have one pair per joint of it."""

from typing import TYPE_CHECKING, Annotated, Any, Literal, Self

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, field_validator, model_validator

from gainfarm import plugins
from gainfarm.analytic.tuning import defaults
from gainfarm.analytic.tuning.algorithms import STEADY_STATE, steady_state_refusal
from gainfarm.analytic.tuning.defaults import REFERENCE_POINT
from gainfarm.analytic.tuning.termination import (
    CONVERGENCE_TOLERANCE,
    CONVERGENCE_WINDOW,
    Termination,
)
from gainfarm.cli.words import counted
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES, EpisodeSpec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec

if TYPE_CHECKING:
    from gainfarm.analytic.tuning.search_space import SearchSpace
    from gainfarm.schemas.robot import Robot

PositiveFinite = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class RunConfig(BaseModel):
    """Everything that decides a run's outcome (plus how to keep its episodes)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pop: int = Field(
        defaults.POP, ge=defaults.POP_MIN, le=defaults.POP_MAX, description="population size"
    )
    seed: int = Field(defaults.SEED, ge=0)
    trajectories: tuple[TrajectorySpec, ...] = Field((TrajectorySpec(),), min_length=1)
    plant: PlantSpec = Field(
        default_factory=PlantSpec,
        validate_default=True,  # the default plant written out too, as a given one is
        # "model" in files written before the plant had its own word (docs/architecture.md)
        validation_alias=AliasChoices("plant", "model"),
    )
    generations: int | None = Field(None, ge=defaults.GENERATIONS_MIN)
    evaluations: int | None = Field(None, ge=defaults.EVALUATIONS_MIN)
    tolerance: float = Field(CONVERGENCE_TOLERANCE, gt=0)
    window: int = Field(CONVERGENCE_WINDOW, ge=1)
    reference_point: tuple[float, float] = REFERENCE_POINT
    asynchronous: bool = Field(
        False, description="a steady state (NSGA-II's or TPE's), not generational"
    )
    algorithm: str = Field(
        defaults.ALGORITHM,
        pattern=plugins.NAME_PATTERN,
        description="the optimiser, a name of the gainfarm.algorithms plug-in group: pymoo's "
        "NSGA-II, NSGA-III, SMS-EMOA, MOEA/D or AGE-MOEA-II, Optuna's TPE, uniform random "
        "sampling, or a plug-in's, registered or installed here (TuningRun.create refuses one "
        "it cannot load)",
    )
    from_defaults: bool = Field(
        False,
        exclude_if=lambda chosen: not chosen,  # a config.json as it was without it
        description="the optimiser's first population holds the default gains (pymoo's "
        "algorithms; `analytic start`'s main job does, RunConfig's plain problem and the "
        "experiments sample at random)",
    )
    objectives: tuple[str, str] = Field(
        DEFAULT_OBJECTIVES,
        description="the two objectives, by name, in the gainfarm.objectives plug-in group: the "
        "paper's f_acc and f_t, or f_t_joint or a plug-in's in place of either, installed here "
        "and on the workers; each declares its unit and direction (a maximised one is told the "
        "optimiser negated), and the records' columns, figures and reports are named after them",
    )
    objective_scaling: defaults.ObjectiveScaling = Field(
        defaults.OBJECTIVE_SCALING,
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
    balance: bool = Field(
        defaults.BALANCE,
        exclude_if=lambda balance: balance == defaults.BALANCE,  # a config.json as it was
        description="a new run given no `objective_weights` (generic) or `plant_scales` "
        "(robust) has them found first, by the default gains' scores simulated in the calling "
        "process (analytic.compose.balanced), so that each trajectory and plant counts alike; "
        "False: the plain means and worsts",
    )
    plant_scales: tuple[tuple[PositiveFinite, PositiveFinite], ...] | None = Field(
        None,
        exclude_if=lambda scales: scales is None,  # a config.json as it was without them
        description="robust tuning: each episode's objectives are scaled by these (first, "
        "second) pairs, one per trajectory and plant in the order of the job ids, before they are "
        "aggregated over the plants (schemas.objectives.plant_scales: each plant counts alike at "
        "the default gains); None: as they are",
    )
    plants: tuple[PlantSpec, ...] = Field(
        (),
        max_length=64,
        description="robust tuning: plant variants every candidate is scored on besides the "
        "nominal `model`, the same for every candidate (analytic.tuning.plants draws them from "
        "the uncertainty ranges); none: the nominal plant alone",
    )
    check_plants: tuple[PlantSpec, ...] = Field(
        (),
        max_length=256,
        description="the held-out check: plants drawn like `plants` on another stream of the "
        "seed, which the named controllers and the default gains run on once the run ends "
        "(analytic.tuning.check); none: no check",
    )
    aggregate: Literal["mean", "worst", "cvar"] = Field(
        "cvar",  # the experiments' robust runs, as they ran; `analytic start`'s is worst
        description="each trajectory's objectives over the nominal plant and its variants, "
        "objective by objective: the mean, the worst (a bound that holds on every plant), or the "
        "mean of the worst quarter (schemas.objectives.CVAR_SHARE)",
    )
    limits: Limits = Field(
        Limits(),
        description="the safety limits every episode of a candidate must keep to, or it is "
        "infeasible: never on the front (schemas.limits; a config.json from before them reads "
        "the defaults, one from before a limit does not check it)",
    )
    keep: defaults.Keep = Field(
        defaults.KEEP,
        description="which episode logs the run directory keeps: the front's (the workers keep "
        "every log and the front's are fetched), or all (each comes with its result)",
    )
    feedforward: str | None = Field(
        None,
        pattern=r"^[0-9a-f]{64}$",
        description="SHA-256 of the learned inverse-dynamics model every episode adds to its PD "
        "(the gains are tuned on top); the run directory keeps the file as feedforward.npz",
    )
    replicate: bool = Field(
        defaults.REPLICATE,
        description="on a farm not its own, the analytic process reruns each front member's "
        "episodes itself (the referee): each worker's log must be its own bit for bit, and the "
        "scores the log's (analytic/evaluators/replication.py)",
    )
    spot_checks: float | None = Field(
        defaults.SPOT_CHECKS,
        ge=0,
        le=1,
        description="with `replicate`, the share of every worker's episodes, drawn at random as "
        "they return, that the referee runs again too: a worker lying about episodes that never "
        "reach the front is caught as well. None: sized as the run first starts, so that a "
        "worker lying on a tenth of its share of the run's episodes is caught with probability "
        "0.99 (analytic.evaluators.replication.sized_rate; the run's records keep the rate)",
    )

    @model_validator(mode="before")
    @classmethod
    def _centred_on_the_robot(cls, data: Any) -> Any:
        # No trajectory given: the default one, placed at the centre of the robot's workspace,
        # of its default duration there (a file written before other arms always names its
        # trajectories).
        if not isinstance(data, dict) or "trajectories" in data:
            return data
        plant = data.get("plant", data.get("model"))
        name = plant.robot if isinstance(plant, PlantSpec) else (plant or {}).get("robot")
        if not isinstance(name, str) or name not in plugins.names(plugins.ROBOTS):
            return data  # the plant's own check says what is wrong with it
        trajectory = TrajectorySpec(center=_robot(name).workspace.center)
        if name != DEFAULT_ROBOT:  # the iiwa 14's is the standard 5 s (RunConfig() stays cheap)
            # start-up: the references (SciPy, MuJoCo) load for another arm's default only
            from gainfarm.worker.reference import default_duration

            trajectory = trajectory.model_copy(
                update={"duration": default_duration(trajectory, name)}
            )
        return {**data, "trajectories": (trajectory,)}

    @field_validator("limits", mode="before")
    @classmethod
    def _as_they_were(cls, limits: object) -> object:
        # Limits as a stored config.json names them (a command line's are a Limits already): one
        # it lacks did not exist when the run ran and was not checked, so it is not now; its
        # default would change a resumed run's constraints (the lag, and the damping's bound).
        if isinstance(limits, dict):
            return {name: None for name in Limits.model_fields} | limits
        return limits

    @field_validator("algorithm")
    @classmethod
    def _an_algorithm_here(cls, name: str) -> str:
        return plugins.check_name(plugins.ALGORITHMS, name)

    @field_validator("objectives")
    @classmethod
    def _objectives_here(cls, names: tuple[str, str]) -> tuple[str, str]:
        if names[0] == names[1]:
            raise ValueError(f"objectives: {names[0]!r} twice; name two different ones")
        for name in names:
            plugins.check_name(plugins.OBJECTIVES, name)
        return names

    @field_validator("plant")
    @classmethod
    def _a_robot_here(cls, plant: PlantSpec) -> PlantSpec:
        plugins.check_name(plugins.ROBOTS, plant.robot)
        return _resolved(plant)

    @field_validator("plants", "check_plants")
    @classmethod
    def _variants_written_out(cls, plants: tuple[PlantSpec, ...]) -> tuple[PlantSpec, ...]:
        for plant in plants:
            plugins.check_name(plugins.ROBOTS, plant.robot)
        return tuple(_resolved(plant) for plant in plants)

    @model_validator(mode="after")
    def _one_robot(self) -> Self:
        for field in ("plants", "check_plants"):
            other = next((p.robot for p in getattr(self, field) if p.robot != self.robot), None)
            if other is not None:
                raise ValueError(
                    f"{field}: a variant of {other}, not of the run's robot {self.robot}"
                )
        return self

    @field_validator("trajectories")
    @classmethod
    def _kinds_here(cls, trajectories: tuple[TrajectorySpec, ...]) -> tuple[TrajectorySpec, ...]:
        for trajectory in trajectories:
            plugins.check_name(plugins.TRAJECTORIES, trajectory.kind)
        return trajectories

    @model_validator(mode="after")
    def _one_termination(self) -> Self:
        if self.generations is not None and self.evaluations is not None:
            raise ValueError("generations and evaluations exclude each other")
        if self.asynchronous and self.algorithm not in STEADY_STATE:
            raise ValueError(steady_state_refusal(self.algorithm))
        weights = self.objective_weights
        if weights is not None and len(weights) != len(self.trajectories):
            raise ValueError(
                f"objective_weights: {len(weights)} pairs for {len(self.trajectories)} "
                "trajectories (one pair per trajectory)"
            )
        scales = self.plant_scales
        episodes = len(self.trajectories) * (1 + len(self.plants))
        if scales is not None and len(scales) != episodes:
            raise ValueError(
                f"plant_scales: {len(scales)} pairs for {episodes} episodes (one pair per "
                "trajectory and plant)"
            )
        return self

    @property
    def termination(self) -> Termination:
        return Termination(self.generations, self.evaluations, self.tolerance, self.window)

    @property
    def robot(self) -> str:
        """The name of the robot the run tunes (its plant's)."""
        return self.plant.robot

    @property
    def arm(self) -> "Robot":
        """The robot the run tunes, loaded (its plug-in)."""
        return _robot(self.robot)

    @property
    def default_gains(self) -> PDGains:
        """The robot's default gains: the search space's centre, what the run is judged
        against (the baseline, the held-out check) and its first population's first member."""
        return self.arm.default_gains

    @property
    def space(self) -> "SearchSpace":
        """The gains the run searches: the space around the robot's default gains."""
        # start-up: the search space imports numpy, which `from gainfarm import RunConfig` spares
        from gainfarm.analytic.tuning.search_space import SearchSpace

        return SearchSpace.around(self.default_gains)

    def episode_spec(self, gains: PDGains, trajectory: int, plant: int = 0) -> EpisodeSpec:
        """The episode of `gains` on the run's trajectory `trajectory` (0-based) and plant
        `plant` (0: the nominal, k: the k-th variant): what the run scores a candidate by.
        ValueError if the gains are not one pair per joint of the run's robot."""
        joints = self.arm.joint_names
        if len(gains.kp) != len(joints):
            raise ValueError(
                f"gains: {len(gains.kp)} pairs for {self.robot}'s {len(joints)} joints "
                f"({', '.join(joints)})"
            )
        return EpisodeSpec(
            gains=gains,
            trajectory=self.trajectories[trajectory],
            plant=self.plant if plant == 0 else self.plants[plant - 1],
            feedforward=self.feedforward,
            objectives=self.objectives,
        )

    @property
    def budget(self) -> int | None:
        """The evaluations the run may spend (--evaluations, or --generations times the
        population); None for a run that stops on convergence."""
        return self.evaluations or (self.generations * self.pop if self.generations else None)

    @property
    def termination_text(self) -> str:
        if self.generations:
            return counted(self.generations, "generation")
        if self.evaluations:
            return counted(self.evaluations, "evaluation")
        return f"until converged ({self.termination.rule})"

    @property
    def mode(self) -> str:
        return "specific" if len(self.trajectories) == 1 else "generic"


def _robot(name: str) -> "Robot":
    """The robot plug-in `name` (models.robot_of)."""
    # start-up: the robots' modules import MuJoCo, which `from gainfarm import RunConfig` spares
    from gainfarm.models.robots import robot_of

    return robot_of(name)


def _resolved(plant: PlantSpec) -> PlantSpec:
    """The plant with its robot's numbers written out: what the worker logs it ran, and what a
    log is checked against (analytic.evaluators)."""
    # start-up: the robots' modules import MuJoCo, which `from gainfarm import RunConfig` spares
    from gainfarm.models.robots import resolve

    return resolve(plant)
