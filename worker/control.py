"""Control layer: the joint-space torque PD law at 500 Hz.

    tau = sat( Kp (q_des - q) + Kd (qd_des - qd) [+ g(q_des)] )

`torque` is the law as written, for any number of ticks at once. The episode's tick loop uses the
same law rearranged so that each tick costs two small matrix-vector products: everything that
depends only on the reference is folded into a per-tick feed-forward computed once per episode.
"""

from dataclasses import dataclass

import numpy as np

from gainfarm.schemas.gains import PDGains


@dataclass(frozen=True)
class PDController:
    kp: np.ndarray  # (joints,) N·m/rad
    kd: np.ndarray  # (joints,) N·m·s/rad
    torque_limits: np.ndarray  # (joints,) N·m, symmetric saturation

    @classmethod
    def from_gains(cls, gains: PDGains, torque_limits: np.ndarray) -> "PDController":
        return cls(np.array(gains.kp), np.array(gains.kd), np.asarray(torque_limits, dtype=float))

    def torque(
        self,
        q: np.ndarray,
        qd: np.ndarray,
        q_des: np.ndarray,
        qd_des: np.ndarray,
        feedforward: np.ndarray | float = 0.0,
    ) -> np.ndarray:
        """The saturated PD torque; arrays may carry a leading tick axis."""
        raw = self.kp * (q_des - q) + self.kd * (qd_des - qd) + feedforward
        return np.clip(raw, -self.torque_limits, self.torque_limits)

    def reference_term(
        self, q_des: np.ndarray, qd_des: np.ndarray, feedforward: np.ndarray | float = 0.0
    ) -> np.ndarray:
        """Kp q_des + Kd qd_des + feed-forward: the part of the law known before the episode."""
        return self.kp * q_des + self.kd * qd_des + feedforward

    def state_gains(self, link_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Kp·L, Kd·L) so that Kp q = (Kp·L) qpos and Kd qd = (Kd·L) qvel, with q = L qpos."""
        return self.kp[:, None] * link_map, self.kd[:, None] * link_map
