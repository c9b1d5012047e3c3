"""One episode: what to run (EpisodeSpec), what it was (EpisodeMetadata), how it scored (Scores)."""

from typing import Annotated, Any, Self

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, model_validator

from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import JOINT_NAMES, MAX_JOINTS, SPEED_LIMITS, PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD, KIND_PATTERN, TrajectorySpec

# The paper's two objectives, computed from the log by schemas/objectives/. An episode may name
# others, of the gainfarm.objectives plug-in group (a name of the same form as a trajectory
# kind's): its worker computes them, or refuses the job if it lacks the plug-in.
DEFAULT_OBJECTIVES = ("f_acc", "f_t")
ObjectiveName = Annotated[str, Field(pattern=KIND_PATTERN)]


class EpisodeSpec(BaseModel):
    """Everything a worker needs to simulate one episode, and nothing else."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    gains: PDGains
    trajectory: TrajectorySpec = TrajectorySpec()
    plant: PlantSpec = Field(
        default_factory=PlantSpec,
        # "model" in files written before the plant had its own word (docs/architecture.md)
        validation_alias=AliasChoices("plant", "model"),
    )
    gravity_compensation: bool = Field(
        False,
        description="add g(q_des) feed-forward, on a plant whose interface does not compensate "
        "gravity itself (interface torque); the paper tunes a plain PD, so off",
    )
    feedforward: str | None = Field(
        None,
        pattern=r"^[0-9a-f]{64}$",
        description="SHA-256 of a learned inverse-dynamics model (models/dynamics.py) whose "
        "torque for the reference (q_des, qd_des, qdd_des) is added to the PD command; the "
        "worker fetches it from the study once and caches it",
    )
    objectives: tuple[ObjectiveName, ObjectiveName] = Field(
        DEFAULT_OBJECTIVES,
        # Left out of the JSON when they are the paper's: the log's metadata and the wire then
        # carry the very bytes they did before objectives could be chosen.
        exclude_if=lambda names: tuple(names) == DEFAULT_OBJECTIVES,
        description="the two objectives its scores carry (Scores.objectives), minimised: the "
        "built-in f_acc and f_t, or a plug-in's (gainfarm.objectives entry points), installed "
        "on the workers",
    )

    @model_validator(mode="after")
    def _one_feedforward(self) -> Self:
        if self.feedforward is not None and self.gravity_compensation:
            raise ValueError(
                "feedforward and gravity_compensation exclude each other: "
                "an inverse-dynamics model already holds the arm against gravity"
            )
        if self.gravity_compensation and self.plant.interface == "fri":
            raise ValueError(
                "gravity_compensation on a plant with interface fri: the robot already adds "
                "its own gravity compensation (a plant with interface torque does not)"
            )
        return self


# A joint's name as a log carries it (its JointState messages name the joints): a ROS name's
# characters, bounded, so that a hostile log cannot name a joint a megabyte long.
JointName = Annotated[str, Field(pattern=r"^[A-Za-z][A-Za-z0-9_/]{0,63}$")]
SpeedLimit = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class EpisodeMetadata(BaseModel):
    """The MCAP metadata record of an episode log: its spec, provenance and outcome, and what the
    log's readers need of its robot (`spec.plant.robot` names it), which the contract cannot
    look up: its joints' names and its speed limits, beside the torque limits the episode ran
    with. An iiwa 14's log leaves out its names and speeds (their defaults), so its bytes are
    those it had before arms were many; a log from before reads as the iiwa 14's."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    spec: EpisodeSpec
    control_period: float = CONTROL_PERIOD
    ticks_planned: int = Field(ge=1)
    ticks_run: int = Field(ge=0)
    torque_limits: tuple[float, ...] = Field(max_length=MAX_JOINTS)
    joint_names: tuple[JointName, ...] = Field(
        JOINT_NAMES,
        min_length=1,
        max_length=MAX_JOINTS,
        exclude_if=lambda names: tuple(names) == JOINT_NAMES,
        description="the robot's joints, base to flange, as its JointState messages name them",
    )
    speed_limits: tuple[SpeedLimit, ...] = Field(
        SPEED_LIMITS,
        max_length=MAX_JOINTS,
        exclude_if=lambda speeds: tuple(speeds) == SPEED_LIMITS,
        description="rad/s, the robot's data-sheet speed limit per joint (the speed measure's)",
    )
    diverged: bool
    divergence: str = Field("", description="why the episode stopped early, if it did")
    versions: dict[str, str]
    # A property of the spec, not of the ticks, kept with them so that the worker's and the
    # referee's logs agree on it bit for bit, and the scores of a log carry it (worker.stability).
    lag: float = Field(
        0.0,
        description="largest RMS over the ticks run of a joint's angle less its reference's, rad",
    )
    damping: float | None = Field(
        None,
        description="least damping ratio of the closed loop linearised at poses along the "
        "reference (worker.stability); None in logs from before it was measured",
    )

    @model_validator(mode="after")
    def _one_number_per_joint(self) -> Self:
        joints = len(self.joint_names)
        for name in ("torque_limits", "speed_limits"):
            if len(getattr(self, name)) != joints:
                raise ValueError(f"{name}: one per joint of {', '.join(self.joint_names)}")
        gains = len(self.spec.gains.kp)
        if gains != joints:
            raise ValueError(f"spec.gains: {gains} pairs for {joints} joints")
        return self


class Scores(BaseModel):
    """The analytic layer's verdict on one episode, computed from its log alone: the paper's two
    objectives and diagnostics, and the objectives its spec names, if those are others."""

    model_config = ConfigDict(frozen=True)

    f_acc: float = Field(description="mean end-effector position error, m (penalised if diverged)")
    f_t: float = Field(description="mean squared torque change per tick, (N·m)² (paper Eq. 1)")
    max_error: float = Field(description="largest end-effector position error, m")
    saturated_fraction: float = Field(description="share of ticks with a joint at its torque limit")
    diverged: bool
    ticks: int = Field(description="ticks actually simulated")
    # The safety measures (schemas.limits bounds them); 0.0 in scores from before they were
    # measured (an old checkpoint's), which therefore never count as a violation.
    torque_step: float = Field(
        0.0, description="largest torque change in one tick, as a share of its joint's limit"
    )
    speed: float = Field(
        0.0, description="largest measured joint speed, as a share of its data-sheet limit"
    )
    chatter: float = Field(
        0.0,
        description="largest RMS of a joint's command above CHATTER_CUTOFF, as a share of its "
        "torque limit",
    )
    lag: float = Field(
        0.0,
        description="largest RMS over the ticks run of a joint's angle less its reference's, rad",
    )
    damping: float | None = Field(
        None,
        description="least damping ratio of the closed loop along the reference (≤ 0: unstable; "
        "the log's, worker.stability); None for a log from before it was measured",
    )
    values: tuple[float, float] | None = Field(
        None,
        exclude_if=lambda values: values is None,  # the JSON of the paper's scores as it was
        description="the values of the two objectives the spec names (EpisodeSpec.objectives), "
        "in order, when they are not f_acc and f_t; None when they are",
    )

    @property
    def objectives(self) -> tuple[float, float]:
        """The episode's two objectives, as its spec names them: what a candidate is told."""
        return self.values if self.values is not None else (self.f_acc, self.f_t)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Checkpoints from before objectives could be chosen pickled scores without `values`,
        and from before the safety measures without those (read as 0: never a violation), and from
        before the damping margin without it (None: not measured), and from before the lag
        without it (0.0, as the other measures)."""
        fields = state["__dict__"]
        fields.setdefault("values", None)
        fields.setdefault("damping", None)
        for name in ("torque_step", "speed", "chatter", "lag"):
            fields.setdefault(name, 0.0)
        super().__setstate__(state)
