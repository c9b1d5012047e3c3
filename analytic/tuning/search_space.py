"""What NSGA-II searches: two gains per joint of the robot (a Kp and a Kd), each on a log scale
between documented bounds.

A gain matters by its order of magnitude (doubling Kp changes the closed loop as much at 100 as
at 1000 N·m/rad), so each decision variable is log10 of a gain. Bounds are per joint, around the
robot's default controller (`SearchSpace.around`): Kp from a tenth to three times it, Kd from a
tenth to five times it. The distal joints carry less inertia and so get proportionally smaller
gains. The iiwa 14's space is the default (a checkpoint from before other arms holds it).
"""

from dataclasses import dataclass, field

import numpy as np

# The bounds are the contract's (a worker warns about gains far outside them); named here too,
# where the search is.
from gainfarm.schemas.gains import DEFAULT_GAINS, KD_RANGE, KP_RANGE, PDGains


def _scaled(gains: tuple[float, ...], factor: float) -> tuple[float, ...]:
    return tuple(gain * factor for gain in gains)


@dataclass(frozen=True)
class SearchSpace:
    kp_low: tuple[float, ...] = field(default=_scaled(DEFAULT_GAINS.kp, KP_RANGE[0]))
    kp_high: tuple[float, ...] = field(default=_scaled(DEFAULT_GAINS.kp, KP_RANGE[1]))
    kd_low: tuple[float, ...] = field(default=_scaled(DEFAULT_GAINS.kd, KD_RANGE[0]))
    kd_high: tuple[float, ...] = field(default=_scaled(DEFAULT_GAINS.kd, KD_RANGE[1]))

    def __post_init__(self) -> None:
        counts = {len(self.kp_low), len(self.kp_high), len(self.kd_low), len(self.kd_high)}
        if len(counts) != 1:
            raise ValueError(f"a search space's bounds have one number per joint, not {counts}")

    @classmethod
    def around(cls, defaults: PDGains) -> "SearchSpace":
        """The space around a robot's `defaults` (its default gains): KP_RANGE and KD_RANGE
        times each joint's."""
        return cls(
            kp_low=_scaled(defaults.kp, KP_RANGE[0]),
            kp_high=_scaled(defaults.kp, KP_RANGE[1]),
            kd_low=_scaled(defaults.kd, KD_RANGE[0]),
            kd_high=_scaled(defaults.kd, KD_RANGE[1]),
        )

    @property
    def joints(self) -> int:
        """How many joints the gains are for (the decision vector holds twice as many)."""
        return len(self.kp_low)

    @property
    def lower(self) -> np.ndarray:
        """Lower bounds of the decision vector: log10 of (Kp of each joint, Kd of each joint)."""
        return np.log10(np.array(self.kp_low + self.kd_low))

    @property
    def upper(self) -> np.ndarray:
        return np.log10(np.array(self.kp_high + self.kd_high))

    def gains(self, x: np.ndarray) -> PDGains:
        """The controller a decision vector stands for."""
        values = np.power(10.0, np.clip(x, self.lower, self.upper))
        joints = self.joints
        return PDGains(kp=tuple(values[:joints].tolist()), kd=tuple(values[joints:].tolist()))
