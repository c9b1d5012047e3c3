"""What NSGA-II searches: the 14 gains, each on a log scale between documented bounds.

A gain matters by its order of magnitude (doubling Kp changes the closed loop as much at 100 as
at 1000 N·m/rad), so each decision variable is log10 of a gain. Bounds are per joint, around the
default controller: Kp from a tenth to three times it, Kd from a tenth to five times it. The
distal joints carry less inertia and so get proportionally smaller gains.
"""

from dataclasses import dataclass, field

import numpy as np

# The bounds are the contract's (a worker warns about gains far outside them); named here too,
# where the search is.
from gainfarm.schemas.gains import DEFAULT_GAINS, KD_RANGE, KP_RANGE, PDGains
from gainfarm.schemas.robot import N_JOINTS


@dataclass(frozen=True)
class SearchSpace:
    kp_low: tuple[float, ...] = field(default=tuple(k * KP_RANGE[0] for k in DEFAULT_GAINS.kp))
    kp_high: tuple[float, ...] = field(default=tuple(k * KP_RANGE[1] for k in DEFAULT_GAINS.kp))
    kd_low: tuple[float, ...] = field(default=tuple(k * KD_RANGE[0] for k in DEFAULT_GAINS.kd))
    kd_high: tuple[float, ...] = field(default=tuple(k * KD_RANGE[1] for k in DEFAULT_GAINS.kd))

    @property
    def lower(self) -> np.ndarray:
        """Lower bounds of the decision vector: log10 of (Kp A1..A7, Kd A1..A7)."""
        return np.log10(np.array(self.kp_low + self.kd_low))

    @property
    def upper(self) -> np.ndarray:
        return np.log10(np.array(self.kp_high + self.kd_high))

    def gains(self, x: np.ndarray) -> PDGains:
        """The controller a decision vector stands for."""
        values = np.power(10.0, np.clip(x, self.lower, self.upper))
        return PDGains(kp=tuple(values[:N_JOINTS].tolist()), kd=tuple(values[N_JOINTS:].tolist()))
