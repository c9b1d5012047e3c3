"""PD gains: the numbers the genetic algorithm tunes, a Kp and a Kd per joint of the robot."""

import math
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from gainfarm.schemas.robot import JOINT_NAMES, MAX_JOINTS, TORQUE_LIMITS, PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD

Gain = Annotated[float, Field(ge=0, allow_inf_nan=False)]
PerJointGains = Annotated[tuple[Gain, ...], Field(min_length=1, max_length=MAX_JOINTS)]


class PDGains(BaseModel):
    """Joint-space PD gains: Kp in N·m/rad and Kd in N·m·s/rad, one per joint of the robot, base
    to flange (who runs them on a robot checks the count against its joints)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kp: PerJointGains
    kd: PerJointGains

    @model_validator(mode="after")
    def _one_pair_per_joint(self) -> "PDGains":
        if len(self.kp) != len(self.kd):
            raise ValueError(f"kp has {len(self.kp)} gains and kd {len(self.kd)}: one per joint")
        return self


# Stiff enough to track every default trajectory within a few centimetres, soft enough not to
# saturate: a sensible first controller, not a tuned one (tuning is the analytic layer's job).
# Kd is deliberately low: on the elastic joints, link-side damping much above this feeds the
# joint's spring mode, and A2/A4 then oscillate with a slowly growing amplitude (Kd 60/40 makes a
# 10 s spiral's torque changes grow a thousandfold); with these, 20 s episodes settle.
DEFAULT_GAINS = PDGains(kp=(2000, 2000, 1200, 1200, 400, 200, 100), kd=(20, 20, 15, 15, 4, 2, 1))

# The bounds the farm's searches span, per joint, as multiples of its default gain (the analytic
# layer's SearchSpace is built on them). They live in the contract so that a worker, which may
# not import the analytic layer, can say when it is handed gains far outside what was searched.
KP_RANGE = (0.1, 3.0)  # × the default Kp of each joint
KD_RANGE = (0.1, 5.0)  # × the default Kd of each joint

# Beyond the bounds by more than this factor (one order of magnitude), gains are no longer a
# variation of anything the farm tuned: most likely a typo or a unit slip (N·m/deg, a lost
# exponent), worth a word before the episode runs.
FAR_OUTSIDE = 10.0

_UNITS = {"kp": "N·m/rad", "kd": "N·m·s/rad"}
# Factors from here on are said as powers of ten: ten million and more are a lost exponent.
HUGE = 1e7


def saturating(
    gains: PDGains,
    plant: PlantSpec,
    joints: tuple[str, ...] = JOINT_NAMES,
    torque_limits: tuple[float, ...] = TORQUE_LIMITS,
) -> tuple[str, str, float] | None:
    """("kp" or "kd", joint, gain) of the first gain that saturates its motor on one count of the
    plant's encoder (an angle of one count, or a velocity of one count over the velocity window):
    with it every tick saturates; None if none does. Exact sensors: a count of the default.
    `joints` and `torque_limits` are the robot's (the iiwa 14's by default)."""
    resolution = plant.sensors.resolution or PlantSpec().sensors.resolution
    speed = resolution / (plant.sensors.velocity_window * CONTROL_PERIOD)
    for which, values, unit in (("kp", gains.kp, resolution), ("kd", gains.kd, speed)):
        for joint, gain, limit in zip(joints, values, torque_limits, strict=True):
            if gain * unit >= limit:
                return which, joint, gain
    return None


def outside_search(
    gains: PDGains, defaults: PDGains = DEFAULT_GAINS, joints: tuple[str, ...] = JOINT_NAMES
) -> str | None:
    """The gain lying furthest beyond the search space's bounds, if more than FAR_OUTSIDE times
    beyond them, said in a phrase ("kd of A3 is 1e-06 N·m·s/rad, 1/1,500,000 of the search
    space's lowest (1.5 N·m·s/rad: 0.1× the default 15)"), which begins with the gain's name,
    kp or kd; None if every gain is nearer. `defaults` and `joints` are the robot's (the search
    space is built on its default gains; the iiwa 14's by default)."""
    worst: tuple[float, str] | None = None
    for which, values, bounds, (low, high) in (
        ("kp", gains.kp, defaults.kp, KP_RANGE),
        ("kd", gains.kd, defaults.kd, KD_RANGE),
    ):
        unit = _UNITS[which]
        for joint, gain, default in zip(joints, values, bounds, strict=True):
            lowest, highest = default * low, default * high
            gain_is = f"{which} of {joint} is {gain:g} {unit}"
            if gain > highest:
                factor = gain / highest
                said = (
                    f"{gain_is}, {_times(factor)}× the search space's highest "
                    f"({highest:g} {unit}: {high:g}× the default {default:g})"
                )
            elif gain < lowest:
                # A gain of 0 is infinitely far below; it reads as "below", not as 1/inf.
                factor = lowest / gain if gain > 0 else math.inf
                part = f"1/{_times(factor)} of" if gain > 0 else "below"
                said = (
                    f"{gain_is}, {part} the search space's lowest "
                    f"({lowest:g} {unit}: {low:g}× the default {default:g})"
                )
            else:
                continue
            # The bounds are products of decimals (15 × 0.1 = 1.5000000000000002): a gain typed
            # as exactly ten times beyond must not tip over on the rounding.
            if factor <= FAR_OUTSIDE * (1 + 1e-9):
                continue
            if worst is None or factor > worst[0]:
                worst = (factor, said)
    return worst[1] if worst is not None else None


def _times(factor: float) -> str:
    """A factor as a person reads it: three figures while small (10.5), whole and grouped once
    large (1,500,000), where more figures would be noise, and as a power of ten once huge
    (1.7e+26), where grouped figures would be a wall of noise."""
    if factor < 100:
        return f"{factor:.3g}"
    return f"{factor:,.0f}" if factor < HUGE else f"{factor:.2g}"
