"""One episode: what to run (EpisodeSpec), what it was (EpisodeMetadata), how it scored (Scores)."""

from pydantic import BaseModel, ConfigDict, Field

from schemas.gains import PDGains
from schemas.robot import ModelSpec
from schemas.trajectory import CONTROL_PERIOD, TrajectorySpec


class EpisodeSpec(BaseModel):
    """Everything a worker needs to simulate one episode, and nothing else."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    gains: PDGains
    trajectory: TrajectorySpec = TrajectorySpec()
    model: ModelSpec = ModelSpec()
    gravity_compensation: bool = Field(
        False, description="add g(q_des) feed-forward; the paper tunes a plain PD, so off"
    )


class EpisodeMetadata(BaseModel):
    """The MCAP metadata record of an episode log: its spec, provenance and outcome."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    spec: EpisodeSpec
    control_period: float = CONTROL_PERIOD
    ticks_planned: int = Field(ge=1)
    ticks_run: int = Field(ge=0)
    torque_limits: tuple[float, ...]
    diverged: bool
    divergence: str = Field("", description="why the episode stopped early, if it did")
    versions: dict[str, str]


class Scores(BaseModel):
    """The analytic layer's verdict on one episode, computed from its log alone."""

    model_config = ConfigDict(frozen=True)

    f_acc: float = Field(description="mean end-effector position error, m (penalised if diverged)")
    f_t: float = Field(description="mean squared torque change per tick, (N·m)² (paper Eq. 1)")
    max_error: float = Field(description="largest end-effector position error, m")
    saturated_fraction: float = Field(description="share of ticks with a joint at its torque limit")
    diverged: bool
    ticks: int = Field(description="ticks actually simulated")
