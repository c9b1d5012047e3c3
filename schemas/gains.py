"""PD gains: the 14 numbers the genetic algorithm tunes."""

import math
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from gainfarm.schemas.robot import JOINT_NAMES, N_JOINTS, TORQUE_LIMITS, PlantSpec
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


def saturating(gains: PDGains, plant: PlantSpec) -> tuple[str, str, float] | None:
    """("kp" or "kd", joint, gain) of the first gain that saturates its motor on one count of the
    plant's encoder (an angle of one count, or a velocity of one count over the velocity window):
    with it every tick saturates; None if none does. Exact sensors: a count of the default."""
    resolution = plant.sensors.resolution or PlantSpec().sensors.resolution
    speed = resolution / (plant.sensors.velocity_window * CONTROL_PERIOD)
    for which, values, unit in (("kp", gains.kp, resolution), ("kd", gains.kd, speed)):
        for joint, gain, limit in zip(JOINT_NAMES, values, TORQUE_LIMITS, strict=True):
            if gain * unit >= limit:
                return which, joint, gain
    return None


def outside_search(gains: PDGains) -> str | None:
    """The gain lying furthest beyond the search space's bounds, if more than FAR_OUTSIDE times
    beyond them, said in a phrase ("kd of A3 is 1e-06 N·m·s/rad, 1/1,500,000 of the search
    space's lowest (1.5 N·m·s/rad: 0.1× the default 15)"), which begins with the gain's name,
    kp or kd; None if every gain is nearer."""
    worst: tuple[float, str] | None = None
    for which, values, defaults, (low, high) in (
        ("kp", gains.kp, DEFAULT_GAINS.kp, KP_RANGE),
        ("kd", gains.kd, DEFAULT_GAINS.kd, KD_RANGE),
    ):
        unit = _UNITS[which]
        for joint, gain, default in zip(JOINT_NAMES, values, defaults, strict=True):
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
