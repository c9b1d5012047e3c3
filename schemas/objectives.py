"""The two objectives of the paper, and a few diagnostics, computed from an episode log alone;
and a candidate's objectives over its trajectory set.

They live in the contract because every package must agree on them: a worker prints the scores of
the episode it ran (`worker episode`) exactly as the analytic side scores the same log.

f_acc = (1/T) Σ_i ||ee_i − ee_des_i||           mean Cartesian error, m
f_t   = (1/T) Σ_i ||u_i − u_(i−1)||²            mean squared torque change per tick, (N·m)²

u is the torque command as applied (/joint_commands), not the joint torque sensors' reading.

f_t sums the joints' raw squared changes, so the big joints (A1, A2: 320 N·m limits against the
wrist's 40) dominate it. f_t_joint, an objective a run may name instead (EpisodeSpec.objectives),
weighs each joint's change by its own limit:

f_t_joint = (1/T) Σ_i Σ_j (τ_ref / τmax_j)² (u_ij − u_(i−1)j)²     (N·m)², τ_ref = max_j τmax_j

Each joint's change is taken as a share of its limit and counted in the largest joint's N·m
(A1's 320): the same share of its limit on every joint counts alike, and the weights, all at
least 1, keep f_t_joint ≥ f_t, so the hypervolume's f_t floor and reference point serve it as
they serve f_t (weights averaging 1 would put a smooth FRI controller's f_t_joint below the floor).

T is the number of ticks the episode was planned to run. u_0, the torque before the first tick,
is taken equal to the first applied torque: the robot was already holding it, so starting does
not count as a change. A diverged episode is scored as if every tick it did not run had the
worst error and the worst torque change, so it is never preferred to one that finished, and the
later it diverged the less it is penalised.

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
gainfarm.objectives group, is a function of the decoded log like `f_acc` and `f_t` here. The
contract loads no plug-in: `score` is given the functions of the ones its log names.
"""

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from gainfarm.schemas.episode import DEFAULT_OBJECTIVES, Scores
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.robot import SPEED_LIMITS

# An objective: the decoded log in, a finite number out, lower is better.
Objective = Callable[[EpisodeLog], float]

DIVERGED_TICK_ERROR = 1.0  # m: more than any real tracking error (the arm's reach is 0.82 m)
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
NO_EPISODE = (10.0, 1e12)


def f_acc(log: EpisodeLog) -> float:
    """Mean Cartesian error over the ticks planned, m; a tick not run counts as
    DIVERGED_TICK_ERROR."""
    meta = log.metadata
    errors = np.linalg.norm(log.ee - log.ee_des, axis=1)
    missing = meta.ticks_planned - log.ticks
    return (float(errors.sum()) + missing * DIVERGED_TICK_ERROR) / meta.ticks_planned


def f_t(log: EpisodeLog) -> float:
    """Mean squared torque change per tick planned, (N·m)²; a tick not run counts as a swing from
    one torque limit to the other on every joint."""
    meta = log.metadata
    limits = np.asarray(meta.torque_limits)
    worst_change = float(np.sum((2.0 * limits) ** 2))
    changes = float(np.sum(np.diff(log.u, axis=0) ** 2))
    missing = meta.ticks_planned - log.ticks
    return (changes + missing * worst_change) / meta.ticks_planned


def joint_weights(limits: Sequence[float]) -> np.ndarray:
    """f_t_joint's weights (τ_ref / τmax_j)², one per joint, τ_ref the largest limit: 1 for the
    strongest joint, more for each weaker one."""
    limits = np.asarray(limits, dtype=float)
    return (limits.max() / limits) ** 2


def f_t_joint(log: EpisodeLog) -> float:
    """f_t with each joint's squared change weighed by joint_weights (see the module's docstring);
    a tick not run counts as every joint's swing from one limit to the other, as in f_t."""
    meta = log.metadata
    limits = np.asarray(meta.torque_limits)
    weights = joint_weights(limits)
    worst_change = float(np.sum(weights * (2.0 * limits) ** 2))
    changes = float(np.sum(weights * np.diff(log.u, axis=0) ** 2))
    missing = meta.ticks_planned - log.ticks
    return (changes + missing * worst_change) / meta.ticks_planned


# The built-in objectives an episode may name besides the paper's two (gainfarm.plugins lists
# them too): computed here, never loaded as plug-ins.
OTHER_OBJECTIVES: dict[str, Objective] = {"f_t_joint": f_t_joint}


def score(log: EpisodeLog, plugins: Mapping[str, Objective] | None = None) -> Scores:
    """The episode's scores. If its spec names objectives other than f_acc and f_t, `plugins`
    gives the function of each (gainfarm.plugins.load); ValueError naming one it lacks."""
    meta = log.metadata
    limits = np.asarray(meta.torque_limits)
    errors = np.linalg.norm(log.ee - log.ee_des, axis=1)
    saturated = np.any(np.abs(log.u) >= limits - SATURATION_TOLERANCE, axis=1)
    built_in = {"f_acc": f_acc(log), "f_t": f_t(log)}
    names = meta.spec.objectives
    values = None
    if names != DEFAULT_OBJECTIVES:
        first, second = (
            built_in[name]
            if name in built_in
            else OTHER_OBJECTIVES[name](log)
            if name in OTHER_OBJECTIVES
            else _plugin_value(name, log, plugins or {})
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
    """The largest measured joint speed, as a share of its data-sheet limit (SPEED_LIMITS),
    at most SPEED_CAP."""
    if not log.ticks:
        return 0.0
    share = float(np.max(np.abs(log.qd) / np.asarray(SPEED_LIMITS)))
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
    # Imported here, not at the top: scipy.signal takes two seconds to import, and the broker
    # and every client import this module for its constants, never scoring an episode.
    from scipy import signal

    meta = log.metadata
    frequencies, density = signal.welch(
        log.u, fs=1.0 / meta.control_period, nperseg=min(CHATTER_SEGMENT, log.ticks), axis=0
    )
    above = frequencies > CHATTER_CUTOFF
    power = density[above].sum(axis=0) * (frequencies[1] - frequencies[0])
    return float(np.max(np.sqrt(power) / np.asarray(meta.torque_limits)))


def _plugin_value(name: str, log: EpisodeLog, plugins: Mapping[str, Objective]) -> float:
    if name not in plugins:
        raise ValueError(f"objective {name!r}: a plug-in, and its function was not given")
    return float(plugins[name](log))


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
) -> tuple[float, float]:
    """A candidate's objectives over its trajectories: the means of each episode's two
    (Scores.objectives: f_acc and f_t, unless the run named others; the generic controller's;
    one trajectory gives the specific controller's), weighted by `weights`, one (first weight,
    second weight) per trajectory (see `balancing_weights`), if given.

    With `plants` > 1, `scores` are each trajectory's episodes on that many plants in turn (the
    nominal first), and each trajectory's objectives are first their `aggregate` (AGGREGATES),
    objective by objective, of the episodes' objectives times `scales`, one (first, second)
    pair per episode, if given (see `plant_scales`)."""
    if not scores or any(score is None for score in scores):
        return NO_EPISODE
    acc = np.array([score.objectives[0] for score in scores])
    t = np.array([score.objectives[1] for score in scores])
    if scales is not None:
        factors = np.asarray(scales, dtype=float).reshape(-1, 2)
        if len(factors) != len(acc):
            raise ValueError(f"{len(factors)} plant scales for {len(acc)} episodes")
        acc, t = acc * factors[:, 0], t * factors[:, 1]
    if plants > 1:
        acc, t = _over_plants(acc, plants, aggregate), _over_plants(t, plants, aggregate)
    if weights is None:
        return float(np.mean(acc)), float(np.mean(t))
    w = np.asarray(weights, dtype=float).reshape(-1, 2)
    if len(w) != len(acc):
        raise ValueError(f"{len(w)} objective weights for {len(acc)} trajectories")
    return float(acc @ w[:, 0] / w[:, 0].sum()), float(t @ w[:, 1] / w[:, 1].sum())


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
