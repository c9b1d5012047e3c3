"""Sensor/actuator layer, part 2: what the robot's sensors report.

Pure NumPy: the tick loop folds these models into its matrices, and the log applies them in bulk
after the episode, so each costs the 2 ms tick as little as possible.

- Encoders: a measured angle is the true one plus Gaussian noise, quantised to whole counts.
- Velocity: the mean of the last `window` differences of measured angles, (c_k − c_(k−w)) / (w·dt),
  as real-time clients compute it (KUKA's interface reports no velocity). Before the episode the
  robot rested, so the differences before tick 0 are zero.
- Torque sensors: the true joint torque plus Gaussian noise.
- Noise is drawn per episode from the sensors' seed, one stream per sensor kind, so an episode is
  reproducible and every candidate evaluated on a trajectory meets the same noise.
"""

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from gainfarm.schemas.robot import Sensors
from gainfarm.schemas.trajectory import CONTROL_PERIOD

LINK, MOTOR, TORQUE = range(3)  # the noise streams: link encoders, motor encoders, torque sensors


def noise(sensors: Sensors, stream: int, ticks: int, scale: float, joints: int) -> np.ndarray:
    """(ticks, joints) Gaussian noise of standard deviation `scale` from the sensors' seed."""
    return _standard_noise(sensors.seed, stream, ticks, joints) * scale


@lru_cache(maxsize=12)  # three streams of four plants' sensors
def _standard_noise(seed: int, stream: int, ticks: int, joints: int) -> np.ndarray:
    """Every episode with the same sensors meets the same noise: drawn once per worker."""
    drawn = np.random.default_rng([seed, stream]).standard_normal((ticks, joints))
    drawn.flags.writeable = False
    return drawn


@dataclass(frozen=True)
class Encoders:
    """Measured angles in counts: c = rint(angle / resolution + noise / resolution), of an arm
    of `joints` joints."""

    sensors: Sensors
    joints: int

    @property
    def count(self) -> float:
        """rad per unit of measurement: one count, or 1 rad if positions are not quantised."""
        return self.sensors.resolution or 1.0

    @property
    def quantised(self) -> bool:
        return self.sensors.resolution > 0

    @property
    def window(self) -> int:
        return self.sensors.velocity_window

    def noise(self, stream: int, ticks: int) -> np.ndarray:
        """The encoders' noise in units of measurement."""
        return noise(self.sensors, stream, ticks, self.sensors.noise / self.count, self.joints)

    def counts(self, angles: np.ndarray, noise_counts: np.ndarray | float = 0.0) -> np.ndarray:
        raw = angles / self.count + noise_counts
        return np.rint(raw) if self.quantised else raw

    def padded(self, counts: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """`counts` after `window` rows of the angles measured at rest before the episode."""
        return np.vstack([np.tile(rest, (self.window, 1)), counts])

    def read(self, padded_counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(angles, velocities) from padded counts: what the sensors report, tick by tick."""
        w = self.window
        angles = padded_counts[w:] * self.count
        velocities = (padded_counts[w:] - padded_counts[:-w]) * (self.count / (w * CONTROL_PERIOD))
        return angles, velocities

    def pd_gains(self, kp: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """G with Kp·angle + Kd·velocity = G @ (c_(k−w), …, c_k), the window of padded counts
        ending at tick k: the PD law on measured angles as one matrix-vector product."""
        w, n = self.window, self.joints
        gains = np.zeros((n, n * (w + 1)))
        rate = kd * self.count / (w * CONTROL_PERIOD)
        gains[:, n * w :] = np.diag(kp * self.count + rate)
        gains[:, :n] -= np.diag(rate)
        return gains
