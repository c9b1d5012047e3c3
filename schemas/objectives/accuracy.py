"""f_acc, the paper's first objective: how far the flange is from where it should be.

f_acc = (1/T) Σ_i ||ee_i − ee_des_i||           mean Cartesian error, m

T is the number of ticks the episode was planned to run; a tick a diverged episode did not run
counts as DIVERGED_TICK_ERROR, so it is never preferred to one that finished, and the later it
diverged the less it is penalised.
"""

import numpy as np

from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.objectives.declaration import MINIMISE, Objective

DIVERGED_TICK_ERROR = 1.0  # m: more than any real tracking error (the arm's reach is 0.82 m)


def mean_error(log: EpisodeLog) -> float:
    """Mean Cartesian error over the ticks planned, m; a tick not run counts as
    DIVERGED_TICK_ERROR."""
    meta = log.metadata
    errors = np.linalg.norm(log.ee - log.ee_des, axis=1)
    missing = meta.ticks_planned - log.ticks
    return (float(errors.sum()) + missing * DIVERGED_TICK_ERROR) / meta.ticks_planned


f_acc = Objective(
    name="f_acc",
    unit="m",
    direction=MINIMISE,
    description="mean end-effector error",
    no_episode=10.0,  # ten times a diverged episode's worst (DIVERGED_TICK_ERROR every tick)
    function=mean_error,
)
