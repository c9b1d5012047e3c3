"""PD gains: the 14 numbers the genetic algorithm tunes."""

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from gainfarm.schemas.robot import JOINT_NAMES, N_JOINTS, TORQUE_LIMITS, ModelSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD

Gain = Annotated[float, Field(ge=0, allow_inf_nan=False)]
PerJointGains = Annotated[tuple[Gain, ...], Field(min_length=N_JOINTS, max_length=N_JOINTS)]


class PDGains(BaseModel):
    """Joint-space PD gains: Kp in N·m/rad and Kd in N·m·s/rad, one per joint A1..A7."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kp: PerJointGains
    kd: PerJointGains


# Stiff enough to track every default trajectory within a few centimetres, soft enough not to
# saturate: a sensible first controller, not a tuned one (tuning is the analytic layer's job).
# Kd is deliberately low: on the elastic joints, link-side damping much above this feeds the
# joint's spring mode, and A2/A4 then oscillate with a slowly growing amplitude (Kd 60/40 makes a
# 10 s spiral's torque changes grow a thousandfold); with these, 20 s episodes settle.
DEFAULT_GAINS = PDGains(kp=(2000, 2000, 1200, 1200, 400, 200, 100), kd=(20, 20, 15, 15, 4, 2, 1))


def saturating(gains: PDGains, model: ModelSpec) -> tuple[str, str, float] | None:
    """("kp" or "kd", joint, gain) of the first gain that saturates its motor on one count of the
    plant's encoder (an angle of one count, or a velocity of one count over the velocity window):
    with it every tick saturates; None if none does. Exact sensors: a count of the default."""
    resolution = model.sensors.resolution or ModelSpec().sensors.resolution
    speed = resolution / (model.sensors.velocity_window * CONTROL_PERIOD)
    for which, values, unit in (("kp", gains.kp, resolution), ("kd", gains.kd, speed)):
        for joint, gain, limit in zip(JOINT_NAMES, values, TORQUE_LIMITS, strict=True):
            if gain * unit >= limit:
                return which, joint, gain
    return None
