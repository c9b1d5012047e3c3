"""f_t, the paper's second objective: how much the torque command changes, tick to tick.

f_t = (1/T) Σ_i ||u_i − u_(i−1)||²            mean squared torque change per tick, (N·m)²

u is the torque command as applied (/joint_commands), not the joint torque sensors' reading.
T is the number of ticks the episode was planned to run. u_0, the torque before the first tick,
is taken equal to the first applied torque: the robot was already holding it, so starting does
not count as a change. A tick a diverged episode did not run counts as the worst change, a swing
from one torque limit to the other on every joint.
"""

import numpy as np

from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.objectives.declaration import MINIMISE, Objective


def mean_squared_change(log: EpisodeLog) -> float:
    """Mean squared torque change per tick planned, (N·m)²; a tick not run counts as a swing from
    one torque limit to the other on every joint."""
    meta = log.metadata
    limits = np.asarray(meta.torque_limits)
    worst_change = float(np.sum((2.0 * limits) ** 2))
    changes = float(np.sum(np.diff(log.u, axis=0) ** 2))
    missing = meta.ticks_planned - log.ticks
    return (changes + missing * worst_change) / meta.ticks_planned


f_t = Objective(
    name="f_t",
    unit="(N·m)²",
    direction=MINIMISE,
    description="mean squared torque change per tick",
    # Beyond a diverged episode's worst: every joint swinging limit to limit every tick is
    # Σ (2 τmax_j)² ≈ 1.4e6 (N·m)² on the iiwa 14, any arm of this class alike.
    no_episode=1e12,
    function=mean_squared_change,
)
