"""f_t_joint: f_t with each joint's change weighed by its torque limit, so that the wrist counts.

f_t sums the joints' raw squared changes, so the big joints (the iiwa 14's A1, A2: 320 N·m limits
against the wrist's 40; the UR5e's 150 against 28) dominate it. f_t_joint, an objective a run may
name instead (`--torque-measure joint`, `--objective f_t_joint`), weighs each joint's change by its
own limit:

f_t_joint = (1/T) Σ_i Σ_j (τ_ref / τmax_j)² (u_ij − u_(i−1)j)²     (N·m)², τ_ref = max_j τmax_j

Each joint's change is taken as a share of its limit and counted in the largest joint's N·m (the
iiwa 14's A1's 320; the limits are the log's own, EpisodeMetadata.torque_limits): the same share of
its limit on every joint counts alike, and the weights, all at least 1, keep f_t_joint ≥ f_t, so the
hypervolume's f_t floor and reference point serve it as they serve f_t (weights averaging 1 would
put a smooth FRI controller's f_t_joint below the floor). A tick not run counts as every joint's
swing from one limit to the other, as in f_t.
"""

from collections.abc import Sequence

import numpy as np

from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.objectives.declaration import MINIMISE, Objective


def joint_weights(limits: Sequence[float]) -> np.ndarray:
    """f_t_joint's weights (τ_ref / τmax_j)², one per joint, τ_ref the largest limit: 1 for the
    strongest joint, more for each weaker one."""
    limits = np.asarray(limits, dtype=float)
    return (limits.max() / limits) ** 2


def weighted_mean_squared_change(log: EpisodeLog) -> float:
    """f_t with each joint's squared change weighed by joint_weights (see the module's docstring);
    a tick not run counts as every joint's swing from one limit to the other, as in f_t."""
    meta = log.metadata
    limits = np.asarray(meta.torque_limits)
    weights = joint_weights(limits)
    worst_change = float(np.sum(weights * (2.0 * limits) ** 2))
    changes = float(np.sum(weights * np.diff(log.u, axis=0) ** 2))
    missing = meta.ticks_planned - log.ticks
    return (changes + missing * worst_change) / meta.ticks_planned


f_t_joint = Objective(
    name="f_t_joint",
    unit="(N·m)²",
    direction=MINIMISE,
    description="mean squared torque change per tick, each joint weighed by its torque limit",
    # As f_t's: the weights (at most 64 on the iiwa 14, 29 on the UR5e) keep a swing below it.
    no_episode=1e12,
    function=weighted_mean_squared_change,
)
