"""PD gains: the 14 numbers the genetic algorithm tunes."""

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from schemas.robot import N_JOINTS

Gain = Annotated[float, Field(ge=0, allow_inf_nan=False)]
PerJointGains = Annotated[tuple[Gain, ...], Field(min_length=N_JOINTS, max_length=N_JOINTS)]


class PDGains(BaseModel):
    """Joint-space PD gains: Kp in N·m/rad and Kd in N·m·s/rad, one per joint A1..A7."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kp: PerJointGains
    kd: PerJointGains
