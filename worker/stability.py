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
"""

import threading
from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np

from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.robot import ModelSpec
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
N = 7


def least_damping(
    spec: EpisodeSpec, reference: Reference | None = None, poses: int = POSES
) -> float:
    """The least damping ratio over the closed loop's modes at `poses` poses along the
    reference: ≤ 0 if the loop is unstable at one of them. Rounded to 1e-6 (a margin needs no
    more), so that hosts whose linear algebra differs in the last bits log the same number."""
    reference = reference_for(spec.trajectory) if reference is None else reference
    plant, gravity = _scratch(spec.model, threading.get_ident())
    loop = ClosedLoop(plant, PDController.from_gains(spec.gains, plant.torque_limits), gravity)
    spans = (np.arange(poses) + 0.5) / poses
    ticks = np.unique((spans * (len(reference.t) - 1)).round().astype(int))
    least = 1.0
    for tick in ticks:
        pose = (reference.q[tick], reference.qd[tick], reference.qdd[tick])
        matrix = loop.closed(_linearised(spec.model, *(part.tobytes() for part in pose)))
        if not np.isfinite(matrix).all():  # gains beyond what the physics can differentiate
            return -1.0
        least = min(least, float(damping_ratios(np.linalg.eigvals(matrix)).min()))
    return round(least, 6) + 0.0  # + 0.0: never −0.0


@lru_cache(maxsize=256)
def _linearised(model: ModelSpec, q: bytes, qd: bytes, qdd: bytes) -> "Linearised":
    """The plant's part of the loop at the pose whose reference is (q, qd, qdd), as bytes: it
    does not depend on the gains, so every candidate on a path shares it, and only the PD law
    is the episode's to add (the differentiation is half the margin's cost, bench/damping.py)."""
    plant, gravity = _scratch(model, threading.get_ident())
    state = pose_state(plant, *(np.frombuffer(part) for part in (q, qd, qdd)))
    linearised = linearise(plant, gravity, *state)
    for part in (linearised.a, linearised.b, linearised.gravity, linearised.friction):
        if part is not None:
            part.flags.writeable = False  # shared by every episode at the pose
    return linearised


@lru_cache(maxsize=32)
def _scratch(model: ModelSpec, thread: int) -> tuple[Plant, RobotGravity | None]:
    """A plant of `model` (and the robot's gravity model, behind FRI) for one thread's
    linearisations: their MjData are scratch space, and making them costs as much as two poses."""
    return Plant(model), RobotGravity(model) if model.interface == "fri" else None


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
        self, plant: Plant, controller: PDController, gravity: RobotGravity | None = None
    ) -> None:
        """`gravity`: the robot's gravity model to differentiate (FRI), if already made."""
        model, spec = plant.model, plant.spec
        _checked(spec)
        self.plant, self.spec = plant, spec
        self.gravity = None
        if spec.interface == "fri":
            self.gravity = RobotGravity(spec) if gravity is None else gravity
        self.window = 0 if spec.sensors.exact else spec.sensors.velocity_window
        self.delay = spec.delay
        nv = model.nv
        self.nx = 2 * nv
        # The measured angles from the state (qpos, qvel); the PD law's gains on the state and
        # on the oldest angle of the window.
        self.measured = np.hstack([plant.feedback_map, np.zeros((N, nv))])
        kp, kd = np.diag(controller.kp), np.diag(controller.kd)
        if spec.sensors.exact:
            rates = np.hstack([np.zeros((N, nv)), plant.feedback_map])
            self.law = -kp @ self.measured - kd @ rates
            self.oldest = np.zeros((N, N))
        else:
            per_tick = kd / (self.window * CONTROL_PERIOD)
            self.law = -(kp + per_tick) @ self.measured
            self.oldest = per_tick

    @property
    def size(self) -> int:
        return self.nx + N * (self.window + self.delay)

    def at(self, qpos: np.ndarray, qvel: np.ndarray, motor_torque: np.ndarray) -> np.ndarray:
        """The closed loop's transition matrix at the state (qpos, qvel), the motors' torque
        `motor_torque` (their command and friction together: the operating point's acceleration
        enters the Jacobians)."""
        return self.closed(linearise(self.plant, self.gravity, qpos, qvel, motor_torque))

    def closed(self, plant: "Linearised") -> np.ndarray:
        """The closed loop's transition matrix, the plant's part of it `plant` (linearise)."""
        nx, w, d = self.nx, self.window, self.delay
        # The command's dependence on the loop's state z = (x, y_{k−1}..y_{k−w}, c_{k−1}..c_{k−d}).
        command = np.zeros((N, self.size))
        command[:, :nx] = self.law
        if w:
            command[:, nx + N * (w - 1) : nx + N * w] = self.oldest
        applied = command.copy() if d == 0 else np.zeros((N, self.size))
        if d:  # the command of d ticks ago acts now
            start = nx + N * w + N * (d - 1)
            applied[:, start : start + N] = np.eye(N)
        if plant.gravity is not None:  # the robot's gravity model at the measured angles
            applied[:, :nx] += plant.gravity
        applied[:, :nx] += plant.friction
        loop = np.zeros((self.size, self.size))
        loop[:nx, :nx] = plant.a
        loop[:nx] += plant.b @ applied
        if w:  # this tick's measured angle joins the window, the others age by one
            loop[nx : nx + N, :nx] = self.measured
            loop[nx + N : nx + N * w, nx : nx + N * (w - 1)] = np.eye(N * (w - 1))
        if d:  # this tick's command joins the delay line
            base = nx + N * w
            loop[base : base + N] = command
            loop[base + N : base + N * d, base : base + N * (d - 1)] = np.eye(N * (d - 1))
        return loop


@dataclass(frozen=True)
class Linearised:
    """A tick of the plant linearised at a pose: x' = a x + b u, u the motors' torque, and the
    parts of that torque the state moves besides the PD law (each (7, nx), on x): the robot's
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
    friction = plant.spec.friction
    motor_velocity = plant.motor_map @ qvel
    coulomb = np.zeros(N)
    slope = np.zeros(N)
    if friction is not None:  # qfrc_applied = −c·tanh(θ̇ / s), from this tick's velocity
        c, s = np.asarray(friction.coulomb), friction.smoothing
        coulomb = -c * np.tanh(motor_velocity / s)
        slope = -c / s / np.cosh(motor_velocity / s) ** 2
    plant_a, plant_b = _tick(plant, qpos, qvel, motor_torque - coulomb, coulomb)
    measured = np.hstack([plant.feedback_map, np.zeros((N, plant.model.nv))])
    by_gravity = None
    if gravity is not None:
        by_gravity = _gravity_slope(gravity, measured[:, : len(qpos)] @ qpos) @ measured
    by_friction = slope[:, None] * np.hstack([np.zeros((N, len(qpos))), plant.motor_map])
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
    steps = EPSILON * np.eye(N)
    torques = gravity.at(np.vstack([angles + steps, angles - steps]))
    return (torques[:N] - torques[N:]).T / (2 * EPSILON)


@lru_cache(maxsize=64)
def _checked(model: ModelSpec) -> None:
    """_check_actuators, once per plant (it costs a sixth of a margin)."""
    _check_actuators(Plant(model))


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
