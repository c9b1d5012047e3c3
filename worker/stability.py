"""A controller's small-signal stability margin: the least damping ratio of its closed loop,
linearised at poses along the reference.

At each pose the tick loop (worker.stepping) is made linear about the arm following the
reference there: the plant's transition Jacobians from MuJoCo's finite differences
(`mjd_transitionFD`), one per physics substep, composed into the tick's; the PD law on the
measured angles; the velocity as the loop computes it (the mean of the last `window` differences
of measured angles, past angles a shift register); the `delay` (past commands another); the
robot's gravity model at the measured angles (FRI: its Jacobian by finite differences); the
motors' Coulomb friction from this tick's velocity (its slope, the tanh's). What a tick does not
do linearly is left out: quantisation (a count is 6 µrad), noise (it does not change the loop),
clamping (a pose along a feasible reference is far from the torque limits).

Each eigenvalue z of the tick's closed-loop matrix is a mode whose continuous-time equivalent
s = ln z / dt has damping ratio ζ = −ln|z| / √(ln²|z| + arg²z): 1 for a real mode that decays
without ringing, 0 on the unit circle (an undamped ring), negative outside it (growing); a real
negative z (a sign flip every tick: chatter at the Nyquist frequency) has arg π, so a small ζ.
No mode is excluded: the closed loop of a PD with positive gains has no integrator (no z = 1 by
construction), and a z of 0 (a register's mode, a deadbeat one) is ζ = 1.

`least_damping`, the number every episode log carries, mixes two kinds of mode. On an elastic
arm the springs' own modes (near 50-60 Hz on the realistic plant, 22-34 Hz with ten times its
rotor inertia, near 18 Hz on the ideal plant's soft springs) are lightly damped under every
controller; the controller's tracking modes (2-40 Hz) are what its gains set. `margins` splits
them (`tracking_modes`), for a reader who wants the controller's own margins:

- a mode is *tracking* if in it each joint's motor moves with its link, *elastic* if the motor
  moves against it: the sign of Re Σ conj(θ) q over the joints, θ and q the mode's motor and
  link angles (its eigenvector's). Why the sign: a joint alone, a rotor J_m on a spring K to a
  link J_l, the PD on the motor angle, has (undamped) modes at the ω² where
  (Kp + K − J_m ω²)(K − J_l ω²) = K². The link's equation gives θ = q (1 − J_l ω² / K), and the
  difference of the two sides is K·Kp > 0 at ω = 0 and −K² < 0 at ω² = K / J_l, so for any
  gain and any rotor one mode lies below K / J_l (θ with q: tracking), one above (θ against q:
  elastic). The split moves with the plant, as no fixed frequency does: with ten times the
  rotor inertia the elastic modes fall to 22 Hz, below the 38 Hz tracking mode of the search
  space's top gains on the realistic plant (whose elastic modes span 38-88 Hz across the search
  space). Measured (`python bench/margins.py --split`: six controllers across the search
  space, command delays 0-9, the spiral and a fourier path), the modes that decide the margins
  (each class's least damped) are clear-cut: |c| ≥ 0.53 on the realistic plant, ≥ 0.92 with
  the ten-times rotor (c the sign's cosine, Re Σ conj(θ) q / (|θ| |q|)), but for two (the
  search space's top gains on the fourier path: a 65 Hz mode, |c| 0.07). On rigid joints
  θ = q: every mode tracks. The register modes (the velocity's window, the delay line; ζ ≥ 0.4
  at 180-290 Hz on the realistic plant) fall on either side; a z of 0 has no motion and counts
  as tracking. Where the rule blurs: on the ideal plant, whose PD feeds back the link angle
  across soft springs, three times the default Kp (above A1's and A2's spring stiffness) makes
  modes in which motor and link share the motion (10 of its 120 deciding modes on the spiral
  have |c| < 0.5). A mixed mode with c ≥ 0 counts as tracking: the tracking margin errs on the
  cautious side.
- the *tracking damping* is the least ζ among the tracking modes over the poses, with its
  mode's natural frequency |s| / 2π: the controller's own stability margin, read as
  least_damping is (a small-signal check at frozen poses, not a prediction of chatter).
- the *delay margin* is how many extra ticks of command delay, beyond the plant's own, the
  tracking modes take and stay stable (ζ > 0 at every pose): each tick of delay adds phase lag
  at every frequency, and a loop with little lag to spare goes unstable first at its tracking
  crossover. The delay changes only the loop's delay line, not the plant's linearisation
  (`_linearised`, cached per plant and pose), so each extra delay costs an eigenvalue problem
  per pose. Read it as "the loop survives its delay + margin ticks": −1 is unstable at its own
  delay, 0 stable there but not with one tick more, MAX_EXTRA_DELAY (8) at least that many
  (the search stops there: `Margins.capped`). The elastic modes are left out of it (their
  damping stays in `least` and `elastic`): with delay they lose damping under many controllers,
  the default gains' among them (on the realistic plant their least damped spring mode, near
  56 Hz, is unstable at 2 ticks, their tracking modes not until 5).
"""

import threading
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np

from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD
from gainfarm.worker.control import PDController
from gainfarm.worker.plant import Plant, RobotGravity
from gainfarm.worker.reference import Reference, reference_for

# Poses along the reference: the middles of as many equal spans of its time. Not its ends: the
# arm rests there, where the motors' Coulomb friction is steepest and damps every mode most.
# Five find the least damping of 40 evenly spaced to within 0.003 on the spiral, fourier and
# pyramid paths for gains across the search space (0.007 at worst), at some 5 % of an episode
# (bench/damping.py).
POSES = 5
EPSILON = 1e-6  # finite-difference step: rad, rad/s, N·m
# Forward differences: the same ζ to 6 digits as central ones, at half the cost (bench/damping.py).
CENTERED = False


def least_damping(
    spec: EpisodeSpec, reference: Reference | None = None, poses: int = POSES
) -> float:
    """The least damping ratio over the closed loop's modes at `poses` poses along the
    reference: ≤ 0 if the loop is unstable at one of them. Rounded to 1e-6 (a margin needs no
    more), so that hosts whose linear algebra differs in the last bits log the same number."""
    reference = reference_for(spec.trajectory, spec.plant.robot) if reference is None else reference
    plant, gravity = _scratch(spec.plant, threading.get_ident())
    loop = ClosedLoop(plant, PDController.from_gains(spec.gains, plant.torque_limits), gravity)
    least = 1.0
    for tick in _pose_ticks(reference, poses):
        pose = (reference.q[tick], reference.qd[tick], reference.qdd[tick])
        matrix = loop.closed(_linearised(spec.plant, *(part.tobytes() for part in pose)))
        if not np.isfinite(matrix).all():  # gains beyond what the physics can differentiate
            return -1.0
        least = min(least, float(damping_ratios(np.linalg.eigvals(matrix)).min()))
    return round(least, 6) + 0.0  # + 0.0: never −0.0


# The delay margin's search stops this many ticks (16 ms) past the spec's own delay: four times the
# top of models/uncertainty.toml's `delay` range (2 ticks), and past where the tracking modes of
# gains across the search space have gone unstable on the realistic plant (bench/margins.py).
MAX_EXTRA_DELAY = 8


@dataclass(frozen=True)
class Margins:
    """A controller's margins on one plant and path (`margins`), each a damping ratio ζ (≤ 0:
    unstable at some pose) with its mode's natural frequency in Hz (rounded to 1e-3; nan if the
    loop could not be linearised, when its ζ is −1 as least_damping's is):

    - `least`: least_damping's number, over every mode;
    - `tracking`, `tracking_hz`: the least damped tracking mode at the spec's own delay;
    - `elastic`, `elastic_hz`: the least damped elastic mode there (None on rigid joints);
    - `delay`, `tracking_at`, `tracking_at_hz`: the least damped tracking mode with the command
      `delay` ticks late (the spec's own delay unless asked otherwise);
    - `delay_margin`: the extra ticks of command delay, beyond the spec's own, the tracking modes
      take and stay stable: stable at every delay from the spec's to spec's + margin, unstable
      at one more tick. −1: unstable at the spec's own delay already. MAX_EXTRA_DELAY: stable
      through that many extra ticks, where the search stops ("that many or more": `capped`).
    """

    least: float
    tracking: float
    tracking_hz: float
    elastic: float | None
    elastic_hz: float | None
    delay: int
    tracking_at: float
    tracking_at_hz: float
    delay_margin: int

    @property
    def capped(self) -> bool:
        """Whether the delay margin is the search's cap: the loop may take more."""
        return self.delay_margin >= MAX_EXTRA_DELAY


# (ζ, Hz) of a class's least damped mode over the poses; None: the class has no mode.
Least = tuple[float, float] | None


def margins(
    spec: EpisodeSpec,
    delay: int | None = None,
    reference: Reference | None = None,
    poses: int = POSES,
) -> Margins:
    """The margins of `spec`'s controller on its plant along its reference (Margins), the
    tracking damping also at a command `delay` in ticks (default: the spec's own), at the
    `poses` poses least_damping uses. Pure: the plant's linearisations are cached per (plant,
    pose), so every delay, and least_damping, shares them."""
    reference = reference_for(spec.trajectory, spec.plant.robot) if reference is None else reference
    nominal = spec.plant.delay
    delay = nominal if delay is None else delay
    if delay < 0:
        raise ValueError(f"delay {delay}: a command cannot act before it is made")
    ticks = _pose_ticks(reference, poses)
    found: dict[int, tuple[Least, Least]] = {}

    def at(ticks_late: int) -> tuple[Least, Least]:
        if ticks_late not in found:
            found[ticks_late] = _least_modes(spec, reference, ticks, ticks_late)
        return found[ticks_late]

    tracking, elastic = at(nominal)
    tracking_at = at(delay)[0]
    assert tracking is not None and tracking_at is not None  # every loop has tracking modes
    return Margins(
        least=least_damping(spec, reference, poses),
        tracking=tracking[0],
        tracking_hz=tracking[1],
        elastic=None if elastic is None else elastic[0],
        elastic_hz=None if elastic is None else elastic[1],
        delay=delay,
        tracking_at=tracking_at[0],
        tracking_at_hz=tracking_at[1],
        delay_margin=_delay_margin(lambda extra: _stable(at(nominal + extra)[0])),
    )


def _stable(tracking: Least) -> bool:
    return tracking is not None and tracking[0] > 0


def _delay_margin(stable: Callable[[int], bool]) -> int:
    """The extra ticks of delay before the first at which `stable` fails, less one (Margins)."""
    for extra in range(MAX_EXTRA_DELAY + 1):
        if not stable(extra):
            return extra - 1
    return MAX_EXTRA_DELAY


def _pose_ticks(reference: Reference, poses: int) -> np.ndarray:
    """The ticks of the reference's poses: the middles of `poses` equal spans of its time."""
    spans = (np.arange(poses) + 0.5) / poses
    return np.unique((spans * (len(reference.t) - 1)).round().astype(int))


def _least_modes(
    spec: EpisodeSpec, reference: Reference, ticks: np.ndarray, delay: int
) -> tuple[Least, Least]:
    """The least damped (tracking, elastic) modes over the poses at `ticks`, the command `delay`
    ticks late, each rounded as least_damping rounds (hosts agree on them)."""
    plant, gravity = _scratch(spec.plant, threading.get_ident())
    controller = PDController.from_gains(spec.gains, plant.torque_limits)
    loop = ClosedLoop(plant, controller, gravity, delay=delay)
    least: list[Least] = [None, None]
    for tick in ticks:
        pose = (reference.q[tick], reference.qd[tick], reference.qdd[tick])
        matrix = loop.closed(_linearised(spec.plant, *(part.tobytes() for part in pose)))
        if not np.isfinite(matrix).all():  # as least_damping: gains beyond the physics
            failed = (-1.0, float("nan"))
            return failed, (failed if plant.elastic else None)
        z, vectors = np.linalg.eig(matrix)
        ratios, hz = damping_ratios(z), natural_hz(z)
        tracking = tracking_modes(plant, vectors)
        for index, modes in enumerate((tracking, ~tracking)):
            if modes.any():
                weakest = np.flatnonzero(modes)[ratios[modes].argmin()]
                mode = (float(ratios[weakest]), float(hz[weakest]))
                if least[index] is None or mode[0] < least[index][0]:
                    least[index] = mode
    return _rounded(least[0]), _rounded(least[1])


def _rounded(mode: Least) -> Least:
    return None if mode is None else (round(mode[0], 6) + 0.0, round(mode[1], 3) + 0.0)


def natural_hz(z: np.ndarray) -> np.ndarray:
    """The natural frequency |s| / 2π of each discrete-time eigenvalue z, s = ln z / dt (the
    module's docstring): a z of 0 (deadbeat) is infinitely fast."""
    with np.errstate(divide="ignore"):
        return np.abs(np.log(z.astype(complex))) / (2 * np.pi * CONTROL_PERIOD)


def tracking_modes(plant: Plant, vectors: np.ndarray) -> np.ndarray:
    """Which modes (the columns of the closed loop's eigenvectors `vectors`) are tracking ones:
    those in which each joint's motor moves with its link, Re Σ conj(θ) q ≥ 0 over the joints'
    motor angles θ and link angles q (the module's docstring says why). The others, the motor
    against its link, are the elastic joints' spring modes. On rigid joints θ = q: every mode
    tracks."""
    positions = vectors[: plant.model.nq]
    motor, link = plant.motor_map @ positions, plant.link_map @ positions
    return np.real(np.sum(np.conj(motor) * link, axis=0)) >= 0


@lru_cache(maxsize=256)
def _linearised(spec: PlantSpec, q: bytes, qd: bytes, qdd: bytes) -> "Linearised":
    """The plant's part of the loop at the pose whose reference is (q, qd, qdd), as bytes: it
    does not depend on the gains, so every candidate on a path shares it, and only the PD law
    is the episode's to add (the differentiation is half the margin's cost, bench/damping.py)."""
    plant, gravity = _scratch(spec, threading.get_ident())
    state = pose_state(plant, *(np.frombuffer(part) for part in (q, qd, qdd)))
    linearised = linearise(plant, gravity, *state)
    for part in (linearised.a, linearised.b, linearised.gravity, linearised.friction):
        if part is not None:
            part.flags.writeable = False  # shared by every episode at the pose
    return linearised


@lru_cache(maxsize=32)
def _scratch(plant: PlantSpec, thread: int) -> tuple[Plant, RobotGravity | None]:
    """A plant of `model` (and the robot's gravity model, behind FRI) for one thread's
    linearisations: their MjData are scratch space, and making them costs as much as two poses."""
    return Plant(plant), RobotGravity(plant) if plant.interface == "fri" else None


def damping_ratios(z: np.ndarray) -> np.ndarray:
    """ζ of each discrete-time eigenvalue `z` (see the module's docstring)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        decay = -np.log(np.abs(z))
        ratios = decay / np.hypot(decay, np.angle(z))
    return np.where(np.abs(z) > 0, ratios, 1.0)


def operating_point(
    plant: Plant, reference: Reference, tick: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(qpos, qvel, motor torque) of the arm following the reference exactly at `tick`."""
    return pose_state(plant, reference.q[tick], reference.qd[tick], reference.qdd[tick])


def pose_state(
    plant: Plant, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(qpos, qvel, motor torque) of the arm at link angles, velocities and accelerations (q,
    qd, qdd), each spring deflected by what its link needs (elastic joints), the motors' torque
    what the whole arm needs (mj_inverse), their friction included."""
    model, data = plant.model, plant.data
    link_index = plant.link_map.argmax(axis=0)  # the joint each hinge belongs to
    motors = plant.motor_map.sum(axis=0) > 0
    springs = ~motors
    mujoco.mj_resetData(model, data)
    data.qpos[:] = np.where(motors, q[link_index], 0.0)
    data.qvel[:] = np.where(motors, qd[link_index], 0.0)
    data.qacc[:] = np.where(motors, qdd[link_index], 0.0)
    stiffness = model.jnt_stiffness[springs] if springs.any() else None
    for _ in range(3 if stiffness is not None else 1):  # deflection: a fixed point, fast
        mujoco.mj_inverse(model, data)
        if stiffness is None:
            break
        # The spring hinges have no motor: their spring must give what mj_inverse asks of them
        # (qfrc_inverse = ... − passive, passive = −K·deflection); the link angle stays q.
        deflection = data.qpos[springs] - data.qfrc_inverse[springs] / stiffness
        data.qpos[springs] = deflection
        data.qpos[motors] = q - deflection
    motor_torque = data.qfrc_inverse[plant.motor_dof_slice].copy()
    return data.qpos.copy(), data.qvel.copy(), motor_torque


class ClosedLoop:
    """The tick loop of one plant and controller, linearised: `at(...)` gives its transition
    matrix on the state (qpos, qvel, the last `window` measured angles, the last `delay`
    commands), as worker.stepping's sensed loop or exact loop computes a tick."""

    def __init__(
        self,
        plant: Plant,
        controller: PDController,
        gravity: RobotGravity | None = None,
        delay: int | None = None,
    ) -> None:
        """`gravity`: the robot's gravity model to differentiate (FRI), if already made; `delay`:
        the command's delay in ticks, if not the plant's own (only the delay line changes: the
        plant's linearisation is the same, so a `Linearised` serves every delay)."""
        model, spec = plant.model, plant.spec
        _checked(spec)
        self.plant, self.spec = plant, spec
        self.gravity = None
        if spec.interface == "fri":
            self.gravity = RobotGravity(spec) if gravity is None else gravity
        self.window = 0 if spec.sensors.exact else spec.sensors.velocity_window
        self.delay = spec.delay if delay is None else delay
        if self.delay < 0:
            raise ValueError(f"delay {self.delay}: a command cannot act before it is made")
        nv, n = model.nv, plant.joints
        self.nx, self.joints = 2 * nv, n
        # The measured angles from the state (qpos, qvel); the PD law's gains on the state and
        # on the oldest angle of the window.
        self.measured = np.hstack([plant.feedback_map, np.zeros((n, nv))])
        kp, kd = np.diag(controller.kp), np.diag(controller.kd)
        if spec.sensors.exact:
            rates = np.hstack([np.zeros((n, nv)), plant.feedback_map])
            self.law = -kp @ self.measured - kd @ rates
            self.oldest = np.zeros((n, n))
        else:
            per_tick = kd / (self.window * CONTROL_PERIOD)
            self.law = -(kp + per_tick) @ self.measured
            self.oldest = per_tick

    @property
    def size(self) -> int:
        return self.nx + self.joints * (self.window + self.delay)

    def at(self, qpos: np.ndarray, qvel: np.ndarray, motor_torque: np.ndarray) -> np.ndarray:
        """The closed loop's transition matrix at the state (qpos, qvel), the motors' torque
        `motor_torque` (their command and friction together: the operating point's acceleration
        enters the Jacobians)."""
        return self.closed(linearise(self.plant, self.gravity, qpos, qvel, motor_torque))

    def closed(self, plant: "Linearised") -> np.ndarray:
        """The closed loop's transition matrix, the plant's part of it `plant` (linearise)."""
        nx, w, d, n = self.nx, self.window, self.delay, self.joints
        # The command's dependence on the loop's state z = (x, y_{k−1}..y_{k−w}, c_{k−1}..c_{k−d}).
        command = np.zeros((n, self.size))
        command[:, :nx] = self.law
        if w:
            command[:, nx + n * (w - 1) : nx + n * w] = self.oldest
        applied = command.copy() if d == 0 else np.zeros((n, self.size))
        if d:  # the command of d ticks ago acts now
            start = nx + n * w + n * (d - 1)
            applied[:, start : start + n] = np.eye(n)
        if plant.gravity is not None:  # the robot's gravity model at the measured angles
            applied[:, :nx] += plant.gravity
        applied[:, :nx] += plant.friction
        loop = np.zeros((self.size, self.size))
        loop[:nx, :nx] = plant.a
        loop[:nx] += plant.b @ applied
        if w:  # this tick's measured angle joins the window, the others age by one
            loop[nx : nx + n, :nx] = self.measured
            loop[nx + n : nx + n * w, nx : nx + n * (w - 1)] = np.eye(n * (w - 1))
        if d:  # this tick's command joins the delay line
            base = nx + n * w
            loop[base : base + n] = command
            loop[base + n : base + n * d, base : base + n * (d - 1)] = np.eye(n * (d - 1))
        return loop


@dataclass(frozen=True)
class Linearised:
    """A tick of the plant linearised at a pose: x' = a x + b u, u the motors' torque, and the
    parts of that torque the state moves besides the PD law (each (joints, nx), on x): the robot's
    gravity model at the measured angles (FRI; else None) and the motors' Coulomb friction
    from this tick's velocity. None of it depends on the gains."""

    a: np.ndarray
    b: np.ndarray
    gravity: np.ndarray | None
    friction: np.ndarray


def linearise(
    plant: Plant,
    gravity: RobotGravity | None,
    qpos: np.ndarray,
    qvel: np.ndarray,
    motor_torque: np.ndarray,
) -> Linearised:
    """The plant's part of the loop at the state (qpos, qvel), the motors' torque `motor_torque`;
    `gravity` the robot's gravity model (FRI), else None."""
    friction, n = plant.spec.friction, plant.joints
    motor_velocity = plant.motor_map @ qvel
    coulomb = np.zeros(n)
    slope = np.zeros(n)
    if friction is not None:  # qfrc_applied = −c·tanh(θ̇ / s), from this tick's velocity
        c, s = np.asarray(friction.coulomb), friction.smoothing
        coulomb = -c * np.tanh(motor_velocity / s)
        slope = -c / s / np.cosh(motor_velocity / s) ** 2
    plant_a, plant_b = _tick(plant, qpos, qvel, motor_torque - coulomb, coulomb)
    measured = np.hstack([plant.feedback_map, np.zeros((n, plant.model.nv))])
    by_gravity = None
    if gravity is not None:
        by_gravity = _gravity_slope(gravity, measured[:, : len(qpos)] @ qpos) @ measured
    by_friction = slope[:, None] * np.hstack([np.zeros((n, len(qpos))), plant.motor_map])
    return Linearised(plant_a, plant_b, by_gravity, by_friction)


def _tick(
    plant: Plant, qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray, applied: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of one tick, its substeps composed along the path they take: x' = A x + B u,
    u the motors' torque (ctrl and a motor's qfrc_applied enter alike: _check_actuators)."""
    model, data = plant.model, plant.data
    mujoco.mj_resetData(model, data)
    data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
    data.qfrc_applied[plant.motor_dof_slice] = applied
    mujoco.mj_forward(model, data)
    nx, nu = 2 * model.nv, model.nu
    tick_a, tick_b = np.eye(nx), np.zeros((nx, nu))
    step_a, step_b = np.empty((nx, nx)), np.empty((nx, nu))
    for _ in range(plant.substeps):
        mujoco.mjd_transitionFD(model, data, EPSILON, CENTERED, step_a, step_b, None, None)
        tick_a, tick_b = step_a @ tick_a, step_a @ tick_b + step_b
        mujoco.mj_step(model, data)
    return tick_a, tick_b


def _gravity_slope(gravity: RobotGravity, angles: np.ndarray) -> np.ndarray:
    """∂(robot's gravity torque)/∂(measured angles) at `angles`, by central differences."""
    n = len(angles)
    steps = EPSILON * np.eye(n)
    torques = gravity.at(np.vstack([angles + steps, angles - steps]))
    return (torques[:n] - torques[n:]).T / (2 * EPSILON)


@lru_cache(maxsize=64)
def _checked(plant: PlantSpec) -> None:
    """_check_actuators, once per plant (it costs a sixth of a margin)."""
    _check_actuators(Plant(plant))


def _check_actuators(plant: Plant) -> None:
    # The motors are plain torque sources on their own hinges (gear 1, no dynamics, no bias), so
    # a torque on a motor's dof (its friction, in qfrc_applied) enters the dynamics as its ctrl.
    model = plant.model
    dofs = model.jnt_dofadr[model.actuator_trnid[:, 0]]
    plain = (
        np.all(model.actuator_gear[:, 0] == 1)
        and np.all(model.actuator_gainprm[:, 0] == 1)
        and np.all(model.actuator_dyntype == mujoco.mjtDyn.mjDYN_NONE)
        and np.all(model.actuator_biastype == mujoco.mjtBias.mjBIAS_NONE)
        and np.array_equal(dofs, np.arange(model.nv)[plant.motor_dof_slice])
    )
    if not plain:
        raise AssertionError("the motors are not plain torque sources on their hinges")
