"""What an arm's logs tell of its plant: linear least squares on the elastic joint's equations.

The plant is Spong's elastic joint behind the robot's torque interface (models/iiwa14.py), of
any arm (the nominal plant names it: its joints, torque limits and rated payload). Per joint,
with θ the motor angle, q the link angle and τ_J the torque sensor's reading:

    motor side:  B θ̈ + F_v θ̇ + F_c tanh(θ̇_measured / s) = τ_command(t − delay) + g_robot − τ_J
    spring:      τ_J = K (θ − q) + D (θ̇ − q̇)
    link side:   τ_J = Σ_i m_i Y_i(q, q̇, q̈) + m_payload Y_payload(q, q̇, q̈)

Each is linear in what it identifies: rotor inertia B and friction F_v, F_c (for each candidate
delay and friction smoothing s: those two are the ones that fit best, a profile), stiffness K
and damping D, and the links' true masses against the robot's model (mass_scale: each link's
inertia scales with its mass, so the inverse dynamics is linear in the scales) and a payload at
the flange: positive by bounds, a physically consistent arm by construction. Derivatives are
Savitzky-Golay's, and every signal of an equation is filtered by the same low-pass (`WINDOW`),
so that what the filter removes (the springs' ringing, noise) is removed from both sides alike.

A command acts over the control period after it is applied (a zero-order hold): the motor
equation compares it with the motion half a tick later, the mean of two ticks' accelerations.
Without that half tick, delays d and d + 1 fit alike.

How sure each number is: a bootstrap over episodes (each resample sums the episodes' normal
equations, so it costs a small solve). A number the logs cannot tell (its bootstrap spread above
`TOLD`, or its term's torque under MIN_SIGNAL times what the fit leaves unexplained) keeps the
nominal value and the shipped range, and says why.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np
from scipy.optimize import lsq_linear
from scipy.signal import savgol_filter

from gainfarm.analytic.calibration.logs import Recording
from gainfarm.models import compile_model, min_substeps, resolve, robot_of
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD
from gainfarm.worker.plant import RobotGravity

WINDOW, ORDER = 41, 3  # Savitzky-Golay: 82 ms, cubic; passes the excitation, not the springs' ring
# Ticks left out: at the start the arm settles from rest with its springs relaxed (a transient
# of the simulation's start, not of the arm), at both ends the filter's edge.
SKIP_START, SKIP_END = 150, WINDOW
MAX_DELAY = 10  # ticks: 20 ms, an order of magnitude beyond FRI's one cycle
BOOTSTRAP = 200  # resamples of the episodes
TOLD = 0.1  # a number is told when its bootstrap spread is below this share of it ...
# ... and the torque only it accounts for (its term's RMS once the other terms' share of its
# column is taken out: what is left when the others explain all they can) is at least this many
# times what the fit leaves unexplained. The residual is the filter's and the model's, the same
# in every episode, so a term below it is bent by it however small the bootstrap spread (a heavy
# rotor's inertia drowns a joint's viscous friction, a smooth Coulomb part looks viscous, a
# flange's torque is the sensor's noise).
MIN_SIGNAL = 2.5
SPREAD = 3.0  # the twin's range: this many bootstrap standard deviations each way ...
FLOOR = 0.05  # ... and at least 5 % each way (what a linear fit of a real arm leaves unmodelled)


@dataclass(frozen=True)
class Estimate:
    """One group of the plant's numbers (per joint, or one): the fit, its spread, and which of
    them the logs told."""

    value: np.ndarray  # the fit; the nominal where not told (the links' masses: their combination)
    spread: np.ndarray  # bootstrap standard deviation of the fit
    told: np.ndarray  # bool, per value
    explained: np.ndarray  # share of the equation's torque variance the fit explains
    why: str = ""  # where not told: the reason


@dataclass(frozen=True)
class Fit:
    """Everything the logs told, and the plant they make."""

    delay: int
    delay_support: float  # share of bootstrap resamples that chose `delay`
    smoothing: "Smoothing"
    rotor_inertia: Estimate
    viscous: Estimate
    coulomb: Estimate
    stiffness: Estimate
    spring_damping: Estimate
    mass_scale: Estimate
    payload: Estimate
    episodes: int
    ticks: int
    notes: list[str] = field(default_factory=list)

    def plant(self, nominal: PlantSpec) -> PlantSpec:
        """`nominal` with the numbers the logs told (its controller's settings kept)."""
        friction = nominal.friction
        if friction is not None:
            friction = friction.model_copy(
                update={
                    "viscous": _tuple(self.viscous),
                    "coulomb": _tuple(self.coulomb),
                    "smoothing": self.smoothing.value,
                }
            )
        twin = nominal.model_copy(
            update={
                "delay": self.delay,
                "rotor_inertia": _tuple(self.rotor_inertia),
                "stiffness": _tuple(self.stiffness),
                "spring_damping": _tuple(self.spring_damping),
                "friction": friction,
                "mass_scale": _tuple(self.mass_scale),
                "payload": float(self.payload.value[0]),
            }
        )
        twin = PlantSpec.model_validate(twin.model_dump())  # every rule of a plant checked
        return twin.model_copy(update={"substeps": max(twin.substeps, min_substeps(twin))})


def _tuple(estimate: Estimate) -> tuple[float, ...]:
    return tuple(float(v) for v in estimate.value)


def identify(
    recordings: Sequence[Recording], nominal: PlantSpec, seed: int = 0, resamples: int = BOOTSTRAP
) -> Fit:
    """Fit the plant's numbers to `recordings`; `nominal` gives the robot's own model (its
    gravity compensation), the friction's smoothing and every number the logs cannot tell; its
    robot is the arm the recordings are of."""
    nominal = resolve(nominal)  # every per-joint number written out: the robot's own
    joints = len(robot_of(nominal).joint_names)
    for recording in recordings:
        if recording.q.shape[1] != joints:
            raise ValueError(
                f"{recording.name}: {recording.q.shape[1]} joints, {nominal.robot} has {joints}"
            )
    rng = np.random.default_rng([seed, 0x63616C6962])  # "calib": its own stream
    weights = rng.multinomial(len(recordings), [1 / len(recordings)] * len(recordings), resamples)
    signals = [_Signals(recording, nominal) for recording in recordings]
    notes: list[str] = []
    if any(s.estimated_motor for s in signals):
        notes.append(
            "no motor-side angles: θ is estimated as q + τ_J / K with the nominal stiffness, "
            "and the stiffness and spring damping cannot be told"
        )
    delay, support, smoothing, motor = _motor_side(signals, weights, nominal)
    spring = _spring(signals, weights, nominal)
    masses = _link_side(signals, weights, nominal)
    return Fit(
        delay=delay,
        delay_support=support,
        smoothing=smoothing,
        rotor_inertia=motor[0],
        viscous=motor[1],
        coulomb=motor[2],
        stiffness=spring[0],
        spring_damping=spring[1],
        mass_scale=masses[0],
        payload=masses[1],
        episodes=len(recordings),
        ticks=sum(s.rows for s in signals),
        notes=notes,
    )


class _Signals:
    """One recording's filtered signals over the ticks the fit uses."""

    def __init__(self, recording: Recording, nominal: PlantSpec):
        period = CONTROL_PERIOD
        self.recording = recording
        self.kept = slice(SKIP_START, recording.ticks - SKIP_END)
        self.rows = self.kept.stop - self.kept.start
        if self.rows < WINDOW:
            raise ValueError(f"{recording.name}: too short to fit")
        q, tau = recording.q, recording.tau
        self.estimated_motor = recording.theta is None
        if recording.theta is None:
            theta = q + tau / np.asarray(nominal.stiffness)
        else:
            theta = recording.theta
        angles, rates = recording.feedback
        self.theta = theta
        self.fed_back_angles, self.fed_back_rates = angles, rates
        self.deflection = theta - q
        self.q = q
        self.qd = self._derivative(q, 1, period)
        self.qdd = self._derivative(q, 2, period)
        self.theta_d = self._derivative(theta, 1, period)
        self.theta_dd = self._derivative(theta, 2, period)

    @staticmethod
    def _derivative(x: np.ndarray, order: int, period: float) -> np.ndarray:
        return savgol_filter(x, WINDOW, ORDER, deriv=order, delta=period, axis=0)

    def smooth(self, x: np.ndarray) -> np.ndarray:
        """The fit's low-pass on `x`, over the kept ticks."""
        return savgol_filter(x, WINDOW, ORDER, axis=0)[self.kept]


def _half_tick(x: np.ndarray) -> np.ndarray:
    """`x` half a tick later: the mean of each tick and the next (the last repeated)."""
    return np.vstack([(x[:-1] + x[1:]) / 2, x[-1:]])


def _normal(rows: np.ndarray, target: np.ndarray) -> np.ndarray:
    """One episode's least-squares sums [AᵀA | Aᵀb | bᵀb] for one joint, as one (p+1, p+1)."""
    augmented = np.column_stack([rows, target])
    return augmented.T @ augmented


def _solve(sums: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The solution, residual and total sum of squares of summed normal equations."""
    p = len(sums) - 1
    gram, moment, total = sums[:p, :p], sums[:p, p], sums[p, p]
    x = np.linalg.lstsq(gram, moment, rcond=None)[0]
    residual = total - 2 * x @ moment + x @ gram @ x
    return x, max(residual, 0.0), total


def _motor_side(
    signals: Sequence[_Signals], weights: np.ndarray, nominal: PlantSpec
) -> tuple[int, float, "Smoothing", tuple[Estimate, Estimate, Estimate]]:
    """The delay, the Coulomb friction's smoothing, and per joint B, F_v, F_c.

    Linear in B, F_v and F_c for a given delay and smoothing; each of those two is the one whose
    least squares leave the least residual (a profile): the delay at the nominal smoothing, the
    smoothing at that delay, the delay again at the smoothing found."""
    limits = np.asarray(robot_of(nominal).limits.torque)
    n = len(limits)
    fri = nominal.interface == "fri"
    gravity = RobotGravity(nominal) if fri else None
    # What does not depend on the delay or the smoothing, per episode.
    inertial, targets, rates = [], [], []
    for s in signals:
        recording = s.recording
        added = gravity.at(s.fed_back_angles) if gravity is not None else 0.0
        inertial.append([s.smooth(_half_tick(s.theta_dd)), s.smooth(_half_tick(s.theta_d))])
        sensed = _half_tick(recording.tau)
        by_delay = []
        for d in range(MAX_DELAY + 1):
            late = recording.command[np.maximum(np.arange(recording.ticks) - d, 0)]
            motor = np.clip(late, -limits, limits) + added if fri else late
            by_delay.append(s.smooth(np.clip(motor, -limits, limits) - sensed))
        targets.append(by_delay)
        rates.append(s.fed_back_rates)

    def sums(delays: Sequence[int], smoothing: float) -> np.ndarray:
        """[delay, episode, joint] normal equations of B, F_v, F_c at `smoothing`."""
        out = np.empty((len(delays), len(signals), n, 4, 4))
        for e, s in enumerate(signals):
            coulomb = s.smooth(np.tanh(rates[e] / smoothing))
            for i, d in enumerate(delays):
                for j in range(n):
                    rows = np.column_stack(
                        [inertial[e][0][:, j], inertial[e][1][:, j], coulomb[:, j]]
                    )
                    out[i, e, j] = _normal(rows, targets[e][d][:, j])
        return out

    delays = list(range(MAX_DELAY + 1))
    nominal_smoothing = nominal.friction.smoothing if nominal.friction is not None else 0.05
    delay = _least_residual(sums(delays, nominal_smoothing), np.ones(len(signals)))
    smoothing = _smoothing(lambda value: sums([delay], value)[0], nominal_smoothing, weights)
    at_smoothing = sums(delays, smoothing.value)
    delay = _least_residual(at_smoothing, np.ones(len(signals)))
    picks = [_least_residual(at_smoothing, w) for w in weights[: min(len(weights), 50)]]
    support = float(np.mean([pick == delay for pick in picks]))
    estimates = _estimates(
        at_smoothing[delay], weights, ("rotor_inertia", "viscous", "coulomb"), nominal
    )
    return delay, support, smoothing, estimates  # type: ignore[return-value]


def _least_residual(sums: np.ndarray, w: np.ndarray) -> int:
    """Which of sums' first axis (candidates) leaves the least residual, each joint's relative
    to its best (no joint's torque scale outweighs another's), with episodes weighted `w`."""
    joints = sums.shape[2]
    residuals = np.array(
        [[_solve(np.tensordot(w, sums[c, :, j], 1))[1] for j in range(joints)]
         for c in range(len(sums))]
    )  # fmt: skip
    return int((residuals / residuals.min(axis=0)).sum(axis=1).argmin())


@dataclass(frozen=True)
class Smoothing:
    """The Coulomb friction's smoothing (one number, rad/s: Friction.smoothing)."""

    value: float
    spread: float  # bootstrap standard deviation of its logarithm
    told: bool


# Factors on the nominal smoothing searched: a coarse grid, then a fine one around its best. The
# residual's least is sharp (a V, not a parabola), and the viscous friction takes up what the
# smoothing misses: 1 % off in it moved a heavy rotor's viscous friction by 6 %.
SMOOTHINGS = 2.0 ** np.arange(-3.0, 3.01, 0.5)
FINE_SMOOTHINGS = 2.0 ** np.arange(-0.5, 0.51, 0.0625)


def _smoothing(
    sums_at: "Callable[[float], np.ndarray]", nominal: float, weights: np.ndarray
) -> Smoothing:
    """The smoothing whose fit leaves the least residual: the best of a grid of factors on the
    nominal, then of a finer grid around it, then a parabola through the least and its
    neighbours in the logarithm; bootstrapped over episodes."""

    def totals(per_episode: np.ndarray, w: np.ndarray) -> np.ndarray:
        joints = per_episode.shape[2]
        residuals = np.array(
            [[_solve(np.tensordot(w, per_episode[g, :, j], 1))[1] for j in range(joints)]
             for g in range(len(per_episode))]
        )  # fmt: skip
        return (residuals / residuals.min(axis=0)).sum(axis=1)

    coarse = nominal * SMOOTHINGS
    every = np.ones(len(weights[0]))
    best = int(totals(np.array([sums_at(float(v)) for v in coarse]), every).argmin())
    if best in (0, len(coarse) - 1):  # at the grid's edge: no least inside it
        return Smoothing(nominal, float("inf"), False)
    grid = coarse[best] * FINE_SMOOTHINGS
    per_episode = np.array([sums_at(float(value)) for value in grid])  # [grid, episode, joint]

    def least(w: np.ndarray) -> float:
        total = totals(per_episode, w)
        k = int(total.argmin())
        if k in (0, len(grid) - 1):
            return float("nan")
        x = np.log(grid[k - 1 : k + 2])
        a, b, _ = np.polyfit(x, total[k - 1 : k + 2], 2)
        return float(np.exp(-b / (2 * a))) if a > 0 else float(grid[k])

    value = least(every)
    draws = np.log([least(w) for w in weights[: min(len(weights), 50)]])
    spread = float(np.std(draws)) if np.isfinite(draws).all() else float("inf")
    told = bool(np.isfinite(value) and spread < np.log1p(TOLD))
    return Smoothing(value if told else nominal, spread, told)


def _spring(
    signals: Sequence[_Signals], weights: np.ndarray, nominal: PlantSpec
) -> tuple[Estimate, Estimate]:
    """Per joint K and D, from the deflection the two sides' angles show."""
    if any(s.estimated_motor for s in signals):
        return (
            _untold(nominal.stiffness, "no motor-side angles in the logs"),
            _untold(nominal.spring_damping, "no motor-side angles in the logs"),
        )
    n = len(nominal.rotor_inertia)  # type: ignore[arg-type]
    sums = np.empty((len(signals), n, 3, 3))
    for e, s in enumerate(signals):
        deflection = s.smooth(s.deflection)
        rate = s.smooth(s.theta_d - s.qd)
        target = s.smooth(s.recording.tau)
        for j in range(n):
            sums[e, j] = _normal(np.column_stack([deflection[:, j], rate[:, j]]), target[:, j])
    return _estimates(sums, weights, ("stiffness", "spring_damping"), nominal)  # type: ignore[return-value]


def _link_side(
    signals: Sequence[_Signals], weights: np.ndarray, nominal: PlantSpec
) -> tuple[Estimate, Estimate]:
    """The links' mass scales and a payload, bounded positive, from the link-side torques."""
    N = len(nominal.rotor_inertia)  # type: ignore[arg-type]  # the joints, N as in the docstring
    base = nominal.model_copy(
        update={
            "joints": "rigid",
            "rotor_inertia": (0.0,) * N,
            "friction": None,
            "mass_scale": (1.0,) * N,
            "payload": 0.0,
            "substeps": 1,
            "interface": "torque",
        }
    )
    # The inverse dynamics is linear in each link's scale and in the payload's mass: each
    # column is the torque one more unit of it adds.
    variants = [base.model_copy(update={"mass_scale": _unit(i, N)}) for i in range(N)]
    variants.append(base.model_copy(update={"payload": 1.0}))
    p = N + 1
    sums = np.zeros((len(signals), N, p + 1, p + 1))
    for e, s in enumerate(signals):
        zero = _inverse(base, s)
        columns = [s.smooth(_inverse(variant, s) - zero) for variant in variants]
        target = s.smooth(s.recording.tau) - s.smooth(zero)
        for j in range(N):
            rows = np.column_stack([column[:, j] for column in columns])
            sums[e, j] = _normal(rows, target[:, j])
    # One arm for every joint's equation: the joints' sums stacked.
    total = sums.sum(axis=1)  # (episodes, p + 1, p + 1)
    # Unknowns: each scale's change from 1 (a link at least 5 % of its model's mass, at most
    # 20 times it) and the payload (at most the data sheet's rated payload: 14 kg, the iiwa 14's).
    shift = np.r_[np.ones(N), 0.0]
    lower = np.r_[np.full(N, 0.05), 0.0] - shift
    upper = np.r_[np.full(N, 20.0), robot_of(nominal).rated_payload] - shift

    # The distal links' gravity torques look alike, so their masses trade against each other
    # and the payload: their combination fits the torques to a few hundredths of a N·m while
    # each alone may be tens of per cent off, with a bootstrap spread of a few per cent (the
    # residual is the filter's and the model's, the same in every episode, not noise). The twin
    # keeps the combination, which is what moves the arm, and claims none of them alone.
    def solve(w: np.ndarray) -> np.ndarray:
        summed = np.tensordot(w, total, 1)
        factor = np.linalg.cholesky(summed[:p, :p] + 1e-12 * np.trace(summed[:p, :p]) * np.eye(p))
        rhs = np.linalg.solve(factor, summed[:p, p])
        return lsq_linear(factor.T, rhs, bounds=(lower, upper)).x

    change = solve(np.ones(len(signals)))
    fit = change + shift
    spread = np.array([solve(w) for w in weights]).std(axis=0)
    gram = total.sum(axis=0)
    residual = max(gram[p, p] - 2 * change @ gram[:p, p] + change @ gram[:p, :p] @ change, 0.0)
    explained = np.full(p, 1.0 - residual / max(gram[p, p], 1e-30))
    why = (
        "the links' masses and the payload trade against each other: the logs fit their "
        "combination, not each one"
    )
    untold = np.zeros(p, bool)
    return (
        Estimate(fit[:N], spread[:N], untold[:N], explained[:N], why),
        Estimate(fit[N:], spread[N:], untold[N:], explained[N:], why),
    )


def _unit(i: int, joints: int) -> tuple[float, ...]:
    return tuple(2.0 if k == i else 1.0 for k in range(joints))


def _inverse(spec: PlantSpec, s: _Signals) -> np.ndarray:
    """(n, N) joint torques of the rigid arm `spec` along the recording's link motion."""
    model = compile_model(spec)
    data = mujoco.MjData(model)
    out = np.empty_like(s.q)
    for k, (q, qd, qdd) in enumerate(zip(s.q, s.qd, s.qdd, strict=True)):
        data.qpos[:], data.qvel[:], data.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(model, data)
        out[k] = data.qfrc_inverse
    return out


def _estimates(
    sums: np.ndarray, weights: np.ndarray, names: tuple[str, ...], nominal: PlantSpec
) -> tuple[Estimate, ...]:
    """Per joint least squares of summed normal equations `sums` (episodes, joints, p+1, p+1),
    with a bootstrap over episodes; one Estimate per parameter, named as PlantSpec's fields."""
    p, joints = len(names), sums.shape[1]
    fits, spreads, explained = np.empty((joints, p)), np.empty((joints, p)), np.empty(joints)
    signal = np.empty((joints, p))
    for j in range(joints):
        summed = sums[:, j].sum(axis=0)
        x, residual, total = _solve(summed)
        boot = np.array([_solve(np.tensordot(w, sums[:, j], 1))[0] for w in weights])
        fits[j], spreads[j] = x, boot.std(axis=0)
        explained[j] = 1.0 - residual / max(total, 1e-30)
        unique = 1.0 / np.sqrt(np.diag(np.linalg.pinv(summed[:p, :p])))  # norm left to each column
        signal[j] = np.abs(x) * unique / max(np.sqrt(residual), 1e-30)
    out = []
    for i, name in enumerate(names):
        told = (spreads[:, i] < TOLD * np.abs(fits[:, i])) & (fits[:, i] > 0)
        told &= signal[:, i] >= MIN_SIGNAL
        nominal_values = _nominal(nominal, name)
        out.append(
            _with_nominal(
                Estimate(fits[:, i], spreads[:, i], told, explained),
                nominal_values,
                f"the logs cannot tell {name} (the torque only it explains is under "
                f"{MIN_SIGNAL:g} times what the fit leaves unexplained, or a bootstrap spread "
                f"above {TOLD:.0%})",
            )
        )
    return tuple(out)


def _nominal(nominal: PlantSpec, name: str) -> tuple[float, ...]:
    if name in ("viscous", "coulomb"):
        friction = nominal.friction
        joints = len(nominal.rotor_inertia)  # type: ignore[arg-type]
        return tuple(getattr(friction, name)) if friction is not None else (0.0,) * joints
    return tuple(getattr(nominal, name))


def _with_nominal(estimate: Estimate, nominal: Sequence[float], why: str) -> Estimate:
    """`estimate` with the nominal value wherever it is not told, and the reason."""
    value = np.where(estimate.told, estimate.value, np.asarray(nominal, dtype=float))
    return Estimate(
        value,
        estimate.spread,
        estimate.told,
        estimate.explained,
        "" if estimate.told.all() else why,
    )


def _untold(nominal: Sequence[float], why: str) -> Estimate:
    values = np.asarray(nominal, dtype=float)
    return Estimate(
        values,
        np.full_like(values, np.nan),
        np.zeros(len(values), bool),
        np.zeros(len(values)),
        why,
    )
