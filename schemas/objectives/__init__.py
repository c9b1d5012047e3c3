"""The objectives of the paper, and a few diagnostics, computed from an episode log alone;
and a candidate's objectives over its trajectory set.

They live in the contract because every package must agree on them: a worker prints the scores of
the episode it ran (`worker episode`) exactly as the analytic side scores the same log.

Each objective is an `Objective` (declaration.py): a scoring function of the log and what it is, its
name, unit, direction and a line for reports. The built-ins are declared a module each, as a third
party's would be: f_acc (accuracy.py, the mean Cartesian error, m), f_t (torque_change.py, the mean
squared torque change per tick, (N·m)²) and f_t_joint (joint_torque_change.py, f_t with each joint
weighed by its torque limit). Every number of the robot they read (its torque and speed limits) is
its log's own (EpisodeMetadata): any arm, any joint count. A diverged episode is scored as if every
tick it did not run had the worst error and the worst torque change, so it is never preferred to one
that finished, and the later it diverged the less it is penalised.

And the safety measures schemas.limits bounds, from the ticks run (a diverged episode's too):

torque_step = max_(i,j) |u_ij − u_(i−1)j| / τmax_j     largest torque change in a tick, a share
speed       = max_(i,j) |q̇_ij| / q̇max_j                 largest measured joint speed, a share
chatter     = max_j RMS(u_j above CHATTER_CUTOFF) / τmax_j   the command's content the arm
                                                        cannot follow, a share of the limit
lag         = max_j √((1/n) Σ_i (q_ij − q_des_ij)²)      the worst joint's RMS lag behind its
                                                        reference over the n ticks run, rad

(the saturated fraction, a diagnostic already, is the fourth). The RMS above the cut-off is the
square root of the command's power spectral density (Welch's estimate, 0.5 s Hann segments)
integrated above it: absolute, not a share of the command's power, since a smooth controller's
tiny command would make any share of sensor noise look large.

An episode may name other objectives (EpisodeSpec.objectives): a plug-in's, of the
gainfarm.objectives group, declared as the built-ins are (or a bare function of the decoded
log). The contract loads no plug-in: `score` is given the ones its log names.
"""

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from gainfarm.schemas.episode import DEFAULT_OBJECTIVES, Scores
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.objectives.accuracy import DIVERGED_TICK_ERROR, f_acc
from gainfarm.schemas.objectives.declaration import (
    MAXIMISE,
    MINIMISE,
    Objective,
    declared,
    unknown,
)
from gainfarm.schemas.objectives.joint_torque_change import f_t_joint, joint_weights
from gainfarm.schemas.objectives.torque_change import f_t

__all__ = [
    "DIVERGED_TICK_ERROR",
    "MAXIMISE",
    "MINIMISE",
    "NO_EPISODE",
    "Objective",
    "declared",
    "f_acc",
    "f_t",
    "f_t_joint",
    "joint_weights",
    "no_episode",
    "objectives",
    "score",
    "unknown",
]

SATURATION_TOLERANCE = 1e-9  # N·m: a torque this close to its limit is saturated

# Hz: torque above this is chatter, not control. The arm's lowest elastic modes at the ready
# posture are 19 Hz on the ideal plant's soft joints and 51 Hz on the realistic plant's medium
# ones (models/README.md), and fall to about 10 Hz with the rotor inertia drake's notes estimate:
# above the lowest mode the joint's spring filters the command out before it moves the link, so
# torque there only excites the modes. The references move well below it (a 5 s path, under 2 Hz).
CHATTER_CUTOFF = 10.0
CHATTER_SEGMENT = 256  # ticks per Welch segment: 0.5 s, bins 2 Hz apart
# A measured speed is counted at most this many times its limit: beyond, no limit cares how
# far, and the wire's bound holds whatever a wild simulation does.
SPEED_CAP = 1000.0
# rad: a joint's RMS lag is counted at most this: a joint turns at most 2 x 175° from its
# reference within its position limits (schemas.robot), so beyond it only a wild simulation goes.
LAG_CAP = 2 * math.pi

# The objectives of a candidate with no episode to score (its path out of reach, or lost): worse
# than any diverged episode, so NSGA-II ranks it last and moves on. A plug-in objective in either
# place must stay below its value there (docs/plugins.md).
NO_EPISODE = (f_acc.no_episode, f_t.no_episode)


def no_episode(declarations: Sequence[Objective]) -> tuple[float, ...]:
    """The objectives, as the optimiser is told them, of a candidate with no episode, in a run
    whose objectives are `declarations`: each one's no-episode score (the paper's: NO_EPISODE)."""
    return tuple(objective.told_no_episode for objective in declarations)


# The built-in objectives an episode may name besides the paper's two (gainfarm.plugins lists
# them too): computed here, never loaded as plug-ins.
OTHER_OBJECTIVES: dict[str, Objective] = {"f_t_joint": f_t_joint}


def score(log: EpisodeLog, plugins: Mapping[str, Any] | None = None) -> Scores:
    """The episode's scores. If its spec names objectives other than f_acc and f_t, `plugins`
    gives each plug-in's (gainfarm.plugins.load: an Objective or a bare function); ValueError
    naming one it lacks. The values are as the optimiser is told them (a maximised one negated)."""
    meta = log.metadata
    limits = np.asarray(meta.torque_limits)
    errors = np.linalg.norm(log.ee - log.ee_des, axis=1)
    saturated = np.any(np.abs(log.u) >= limits - SATURATION_TOLERANCE, axis=1)
    built_in = {"f_acc": f_acc(log), "f_t": f_t(log)}
    names = meta.spec.objectives
    values = None
    if names != DEFAULT_OBJECTIVES:
        first, second = (
            built_in[name] if name in built_in else _value(name, log, plugins or {})
            for name in names
        )
        values = (first, second)
    return Scores(
        f_acc=built_in["f_acc"],
        f_t=built_in["f_t"],
        max_error=float(errors.max()) if log.ticks else DIVERGED_TICK_ERROR,
        saturated_fraction=float(saturated.mean()) if log.ticks else 0.0,
        diverged=meta.diverged,
        ticks=log.ticks,
        torque_step=torque_step(log),
        speed=speed(log),
        chatter=chatter(log),
        lag=lag(log),
        damping=meta.damping,
        values=values,
    )


def torque_step(log: EpisodeLog) -> float:
    """The largest torque change in one tick, as a share of its joint's torque limit (at most
    2: limit to limit); the first tick changes nothing (see f_t)."""
    if log.ticks < 2:
        return 0.0
    limits = np.asarray(log.metadata.torque_limits)
    return float(np.max(np.abs(np.diff(log.u, axis=0)) / limits))


def speed(log: EpisodeLog) -> float:
    """The largest measured joint speed, as a share of its data-sheet limit (the robot's, as its
    log carries them: EpisodeMetadata.speed_limits), at most SPEED_CAP."""
    if not log.ticks:
        return 0.0
    share = float(np.max(np.abs(log.qd) / np.asarray(log.metadata.speed_limits)))
    return min(share, SPEED_CAP)


def lag(log: EpisodeLog) -> float:
    """The largest RMS over the ticks run of a joint's measured angle less its reference's, rad,
    at most LAG_CAP. f_acc sees the flange's position only, to which the wrist's last joint (A7)
    adds nothing: this sees every joint."""
    if not log.ticks:
        return 0.0
    rms = np.sqrt(np.mean((log.q - log.q_des) ** 2, axis=0))
    worst = float(np.max(rms))
    return min(worst, LAG_CAP) if math.isfinite(worst) else LAG_CAP


def chatter(log: EpisodeLog) -> float:
    """The largest RMS of a joint's torque command above CHATTER_CUTOFF, as a share of its
    torque limit (at most 2: a detrended command stays within twice its limit)."""
    if log.ticks < 2:
        return 0.0
    # start-up: scipy.signal takes two seconds to import, and the broker and every client
    # import this module for its constants, never scoring an episode
    from scipy import signal

    meta = log.metadata
    frequencies, density = signal.welch(
        log.u, fs=1.0 / meta.control_period, nperseg=min(CHATTER_SEGMENT, log.ticks), axis=0
    )
    above = frequencies > CHATTER_CUTOFF
    power = density[above].sum(axis=0) * (frequencies[1] - frequencies[0])
    return float(np.max(np.sqrt(power) / np.asarray(meta.torque_limits)))


def _value(name: str, log: EpisodeLog, plugins: Mapping[str, Any]) -> float:
    """The objective `name` of `log`, as the optimiser is told it: a built-in's, or a plug-in's
    from `plugins`."""
    if name in OTHER_OBJECTIVES:
        return OTHER_OBJECTIVES[name](log)
    if name not in plugins:
        raise ValueError(f"objective {name!r}: a plug-in, and its function was not given")
    objective = declared(plugins[name], name)
    return objective.minimised(objective(log))


# How a candidate's episodes on the plant variants of one trajectory (the nominal plant first)
# become that trajectory's objectives (robust tuning, `--aggregate`): their mean, the worst, or
# the conditional value at risk, the mean of the worst CVAR_SHARE of them (at least one).
AGGREGATES = ("mean", "worst", "cvar")
CVAR_SHARE = 0.25


def objectives(
    scores: Sequence[Scores | None],
    weights: Sequence[tuple[float, float]] | None = None,
    plants: int = 1,
    aggregate: str = "mean",
    scales: Sequence[tuple[float, float]] | None = None,
    no_episode: tuple[float, float] = NO_EPISODE,
) -> tuple[float, float]:
    """A candidate's objectives over its trajectories: the means of each episode's two
    (Scores.objectives: f_acc and f_t, unless the run named others; the generic controller's;
    one trajectory gives the specific controller's), weighted by `weights`, one (first weight,
    second weight) per trajectory (see `balancing_weights`), if given.

    With `plants` > 1, `scores` are each trajectory's episodes on that many plants in turn (the
    nominal first), and each trajectory's objectives are first their `aggregate` (AGGREGATES),
    objective by objective, of the episodes' objectives times `scales`, one (first, second)
    pair per episode, if given (see `plant_scales`). A candidate with an episode missing scores
    `no_episode`: the run's objectives' (`no_episode(declarations)`), the paper's by default."""
    if not scores or any(score is None for score in scores):
        return no_episode
    first = np.array([score.objectives[0] for score in scores])
    second = np.array([score.objectives[1] for score in scores])
    if scales is not None:
        factors = np.asarray(scales, dtype=float).reshape(-1, 2)
        if len(factors) != len(first):
            raise ValueError(f"{len(factors)} plant scales for {len(first)} episodes")
        first, second = first * factors[:, 0], second * factors[:, 1]
    if plants > 1:
        first = _over_plants(first, plants, aggregate)
        second = _over_plants(second, plants, aggregate)
    if weights is None:
        return float(np.mean(first)), float(np.mean(second))
    w = np.asarray(weights, dtype=float).reshape(-1, 2)
    if len(w) != len(first):
        raise ValueError(f"{len(w)} objective weights for {len(first)} trajectories")
    return float(first @ w[:, 0] / w[:, 0].sum()), float(second @ w[:, 1] / w[:, 1].sum())


def _over_plants(values: np.ndarray, plants: int, aggregate: str) -> np.ndarray:
    """Each trajectory's value over its `plants` episodes (a row each), as `aggregate` says."""
    if len(values) % plants:
        raise ValueError(f"{len(values)} episodes are not {plants} plants' per trajectory")
    rows = values.reshape(-1, plants)
    if aggregate == "mean":
        return rows.mean(axis=1)
    if aggregate == "worst":
        return rows.max(axis=1)
    if aggregate == "cvar":
        worst = max(1, math.ceil(CVAR_SHARE * plants))
        return np.sort(rows, axis=1)[:, -worst:].mean(axis=1)
    raise ValueError(f"aggregate {aggregate!r} is not one of {', '.join(AGGREGATES)}")


def plant_scales(
    reference: Sequence[tuple[float, float]], plants: int
) -> tuple[tuple[float, float], ...]:
    """Scales for `objectives` under which every plant counts alike at the `reference` (the
    default gains' objectives on each trajectory's `plants` plants, the nominal first, in the
    order `objectives` takes): each episode's objective times the reference's on the nominal
    plant over the reference's on its own plant. At the reference every plant of a trajectory
    then scores its nominal values, so a candidate's worst over the plants is as good as the
    reference's exactly when it is as good as the reference on each plant; the objectives keep
    their units. A reference value that is not finite and positive on a plant leaves that
    plant's episodes as they are (a scale of 1)."""
    values = np.array(reference, dtype=float).reshape(-1, plants, 2)
    nominal = values[:, :1, :]
    usable = np.isfinite(values) & (values > 0) & np.isfinite(nominal) & (nominal > 0)
    scales = np.where(usable, nominal / np.where(usable, values, 1.0), 1.0)
    return tuple((float(a), float(t)) for a, t in scales.reshape(-1, 2))


def balancing_weights(
    reference: Sequence[tuple[float, float]],
) -> tuple[tuple[float, float], ...]:
    """Weights for `objectives` under which every trajectory counts alike at the `reference`
    (f_acc, f_t) of each trajectory (the default gains' there): each objective's weight is inversely
    proportional to the reference's value of it, and the weights of an objective sum to 1.

    So a trajectory whose f_t is 40 times the others' (a pyramid's corners) no longer makes up
    most of the mean: at the reference every trajectory contributes the same share, and a
    change counts by how far it moves a trajectory against its own reference. The weighted
    mean keeps the objectives' units (m, (N·m)²).
    """
    values = np.array(reference, dtype=float).reshape(-1, 2)
    if values.size == 0 or not np.all(np.isfinite(values) & (values > 0)):
        raise ValueError("balancing needs a finite, positive f_acc and f_t on every trajectory")
    inverse = 1.0 / values
    weights = inverse / inverse.sum(axis=0)
    return tuple((float(a), float(t)) for a, t in weights)
