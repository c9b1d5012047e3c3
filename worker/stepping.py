"""The tick loop, for many episodes at once: their control, sensor, delay and friction layers as
arrays over the batch, their physics stepped by MuJoCo's own batch engine, `mujoco.batch.Batch`.

An episode's numbers do not depend on the batch it runs in: its arithmetic is the same,
operation for operation, alone or beside others (a matrix product is BLAS's matrix-vector
product for one episode, whether NumPy's `dot` alone or its stacked `matmul` for many; the rest
is elementwise), and a Batch steps each world bit for bit as its own MjData would. So an
episode's log is byte-identical in any batch, and to the loop before the Batch
(tests/worker/test_stepping.py).

Episodes stack when their arrays have the same shapes, their loops the same steps and their
models the same layout (the same `kind()`), at most MAX_STACK of them; a batch of mixed kinds
runs one stack per kind. A stack is one Batch, each episode a world on its own model (the plant
variants of a robust run side by side), all stepped by one call a tick, and the robot's gravity
model of all of them one model of many arms (plant.ArmsGravity). Stacks are shared among
`threads` threads: the Batch releases the GIL while it steps, so the physics of several stacks
runs on as many cores while one thread at a time does the (small) array work of its stack,
taking the GIL back once a tick per stack. An episode alone runs a loop over its own rows and
MjData, cheaper than a stack of one.

Two loops, as before batching: the first wave's lean one for exact sensors without delay or
friction (the ideal plant, kept bit for bit: PD on the state, `ctrl = reference term − G·state`),
and the one with encoders, a delay, motor friction and, behind KUKA's FRI interface, the robot's
gravity model at the measured angles (`command = P · recent measurements`, then `+ g_robot`).
"""

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cache

import mujoco
import numpy as np
from mujoco.batch import Batch

from gainfarm.schemas.trajectory import CONTROL_PERIOD
from gainfarm.worker.plant import ArmsGravity, Plant, RobotGravity
from gainfarm.worker.reference import Reference

CHECK_EVERY = 250  # ticks between divergence checks (0.5 s): cheap, and early enough
MAX_JOINT_ERROR = 1.0  # rad: a tracking error this large is a lost arm, not a tuning trade-off
_STATE = mujoco.mjtState.mjSTATE_QPOS | mujoco.mjtState.mjSTATE_QVEL  # what a tick senses
_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION  # a world's whole state, as a batch holds it
_VELOCITY = mujoco.mjtStage.mjSTAGE_VEL  # a batch's stages computed after a step
# Worlds stepped together at most: beyond some 32 a tick's arrays and worlds no longer stay in
# the caches and each tick costs more than it saves (on the Batch: 32, 64 and 128 worlds cost
# 46.5, 48.6 and 50.3 ms an episode; per-world calls before it, 128 cost 2x).
MAX_STACK = 32
STACK_BYTES = 256 * 2**20  # a stack's logs at most: 32 iiwa episodes of up to 30 s, 7 of 120 s


@dataclass
class Stepped:
    """One episode set up for the loop, and, once run, what it logged.

    `gains` is G (exact loop: Kp q + Kd q̇ = G · state) or P (sensed loop: the command from the
    window of measurements); `measure` the sensed loop's row → measurement matrix; `term` the
    exact loop's per-tick reference term, or the sensed loop's rows with their noise and
    feed-forward filled in (the state columns to come); `rest` the measurements before tick 0.
    """

    plant: Plant
    reference: Reference
    gains: np.ndarray
    term: np.ndarray
    measure: np.ndarray | None = None
    rest: np.ndarray | None = None
    window: int = 0
    quantised: bool = False
    slip: slice = field(default_factory=lambda: slice(0))
    opposing: np.ndarray | None = None  # −Coulomb level per motor, if the joints have friction
    # Whether the robot adds its gravity model at the measured angles (FRI): rad per unit of them.
    # The model itself is the loop's to make: one per lone episode, one of many arms per stack.
    fri: bool = False
    unit: float = 1.0
    # Filled by the loop:
    ticks_run: int = 0
    divergence: str = ""
    state: np.ndarray = field(default_factory=lambda: np.empty(0))  # (ticks, nx) qpos, qvel
    command: np.ndarray = field(default_factory=lambda: np.empty(0))  # (ticks, joints), unclamped
    flange: np.ndarray = field(default_factory=lambda: np.empty(0))  # (ticks, 3)
    measured: np.ndarray = field(default_factory=lambda: np.empty(0))  # (window + ticks, width)
    compensation: np.ndarray = field(
        default_factory=lambda: np.empty(0)
    )  # (ticks, joints) gravity's

    @property
    def ticks(self) -> int:
        return len(self.reference.t)

    @property
    def exact(self) -> bool:
        return self.measure is None

    def kind(self) -> tuple:
        """Episodes of one kind stack: the same array shapes, the same steps in the loop (a
        tick's physics steps too: a stack steps its worlds by one count, and a plant variant with
        stiffer springs needs more)."""
        if self.exact:
            return ("exact", _layout(self.plant.model), self.plant.substeps)
        assert self.measure is not None
        return (
            "sensed",
            _layout(self.plant.model),
            self.plant.substeps,
            self.measure.shape,
            self.window,
            self.plant.spec.delay,
            self.quantised,
            self.slip.indices(self.measure.shape[0]),  # slices are unhashable before 3.12
            self.opposing is not None,
            self.plant.motor_dof_slice.indices(self.plant.model.nv),
            self.fri,
        )


def _layout(model: mujoco.MjModel) -> tuple[int, ...]:
    """A model's sizes (nq, nv, nbody, ...): worlds of one batch must share their MjData's
    layout, which these decide. All of them, to be safe: variants of a plant share them all."""
    return tuple(getattr(model, name) for name in _sizes())


@cache
def _sizes() -> tuple[str, ...]:
    model = mujoco.MjModel.from_xml_string("<mujoco/>")
    return tuple(
        name for name in dir(model) if name.startswith("n") and type(getattr(model, name)) is int
    )


def step_all(
    episodes: Sequence[Stepped],
    threads: int = 1,
    finish: Callable[[Stepped], None] | None = None,
) -> None:
    """Run every episode's tick loop; each gets its log arrays, ticks run and divergence.
    `finish(episode)` is called on each as its stack ends, on the thread that stepped it: what
    follows an episode (its log's encoding) overlaps the stepping of other stacks."""
    kinds: dict[tuple, list[Stepped]] = {}
    for episode in episodes:
        kinds.setdefault(episode.kind(), []).append(episode)
    parts: list[list[Stepped]] = []
    for stack in kinds.values():
        size = min(MAX_STACK, _fitting(stack), -(-len(stack) // max(1, threads)))
        parts.extend(stack[start : start + size] for start in range(0, len(stack), size))

    def run(part: list[Stepped]) -> None:
        _loop(part)
        for episode in part if finish is not None else ():
            finish(episode)

    if threads <= 1 or len(parts) == 1:
        for part in parts:
            run(part)
        return
    with ThreadPoolExecutor(min(threads, len(parts))) as pool:
        for _ in pool.map(run, parts):  # raises the first part's error, if any
            pass


def _fitting(stack: list[Stepped]) -> int:
    """How many of `stack`'s episodes fit STACK_BYTES of logs (rows, measurements, commands,
    flange positions: as many floats a tick as an episode's row and measurement, and ten)."""
    episode = max(stack, key=lambda episode: episode.ticks)
    width = 0 if episode.measure is None else episode.measure.shape[0]
    joints = episode.plant.joints
    width += joints if episode.fri else 0  # the robot's gravity model, logged too
    floats = episode.ticks * (
        episode.plant.model.nq + episode.plant.model.nv + 2 * joints + width + 10
    )
    return max(1, STACK_BYTES // (8 * floats))


def _loop(stack: list[Stepped]) -> None:
    if len(stack) == 1:  # alone: a loop over one episode's rows costs less per tick
        (_exact_alone if stack[0].exact else _sensed_alone)(stack[0])
    else:
        (_exact_loop if stack[0].exact else _sensed_loop)(stack)


# --- many episodes -----------------------------------------------------------------------------
# Logs are (ticks, episodes, ...): a tick's rows of every episode are one block, copied at once.


class _Worlds:
    """A stack's plants as one `mujoco.batch.Batch`: each episode a simulation on its own model
    (set_models: the plant variants of a robust run differ in their numbers, not their layout),
    its state a row that the loop reads and writes in place, every world stepped by one call a
    tick without the GIL.

    The batch is persistent (an MjData per world) and each call ends by computing the position
    and velocity stages at the new state: the next step continues from them rather than
    computing them again (at no cost: bench/episode_bench.py), and a tick's flange position is
    read from them before the tick steps, as a lone world's loop reads it after its first
    substep (the same computation on the same state: the same bits)."""

    def __init__(self, stack: list[Stepped]) -> None:
        first = stack[0].plant
        # One thread: step_all runs stacks side by side on its own threads, each stack's array
        # work beside another's physics (docs/performance.md, "One episode").
        self.batch = Batch(first.model, len(stack), 1, persistent=True)
        self.batch.set_models([episode.plant.model for episode in stack])
        for row, episode in zip(self.batch.state, stack, strict=True):
            mujoco.mj_getState(episode.plant.model, episode.plant.data, row, _INTEGRATION)
        # What a tick senses and what it applies, each one block of the state rows (MuJoCo's
        # state order: qpos then qvel, ctrl then qfrc_applied), so a copy or a ufunc does it.
        self.sensed = _columns(self.batch, "qpos", "qvel")
        self.drive = _columns(self.batch, "ctrl", "qfrc_applied")
        self.site = self.batch.bind("site_xpos")[:, first.flange]
        self.substeps = first.substeps
        self.batch.forward(stage=_VELOCITY)

    def step(self, live: np.ndarray | None) -> None:
        """Every live world one control tick on, its kinematics computed at its new state."""
        self.batch.step(live, self.substeps, _VELOCITY)


def _columns(batch: Batch, first: str, last: str) -> np.ndarray:
    """The (nsim, n) view of the state rows from field `first` through field `last`."""
    start, end = batch.bind(first), batch.bind(last)
    row = batch.state.ctypes.data
    begin = (start.ctypes.data - row) // batch.state.itemsize
    stop = (end.ctypes.data - row) // batch.state.itemsize + end[0].size
    assert stop - begin == start[0].size + end[0].size, f"{first} and {last} are not adjacent"
    return batch.state[:, begin:stop]


def _exact_loop(stack: list[Stepped]) -> None:
    """Exact sensors, no delay, no friction: ctrl = reference term − G · (qpos, qvel).

    MuJoCo clamps each command to the motor's ctrlrange when applying it; the log keeps it
    unclamped, and the episode clamps it in bulk, exactly as MuJoCo did."""
    count, ticks = len(stack), max(episode.ticks for episode in stack)
    nx, n = stack[0].plant.model.nq + stack[0].plant.model.nv, stack[0].plant.joints
    gains = np.stack([episode.gains for episode in stack])  # (B, joints, nx)
    term = np.zeros((ticks, count, n))
    for index, episode in enumerate(stack):
        term[: episode.ticks, index] = episode.term
    states, commands, flanges = (np.empty((ticks, count, width)) for width in (nx, n, 3))
    feedback = np.empty((count, n, 1))
    worlds = _Worlds(stack)
    sensed, command, site = worlds.sensed, worlds.drive[:, :n], worlds.site
    columns, fed_back = states[:, :, :, None], feedback[:, :, 0]
    matmul, subtract, copy = np.matmul, np.subtract, np.copyto
    with np.errstate(all="ignore"):  # a diverging world computes on until its block ends
        for start, stop, live in _segments(stack, states):
            for k in range(start, stop):
                copy(states[k], sensed)
                matmul(gains, columns[k], out=feedback)  # a contiguous copy: BLAS, as alone
                subtract(term[k], fed_back, out=command)
                copy(commands[k], command)
                copy(flanges[k], site)
                worlds.step(live)
    for index, episode in enumerate(stack):
        episode.state, episode.command = states[:, index], commands[:, index]
        episode.flange = flanges[:, index]


def _sensed_loop(stack: list[Stepped]) -> None:
    """Sensors, a delay and friction.

    Each row (qpos, qvel, encoder noise, feed-forward) is known but for its state before the
    episode, so one product turns a sensed row into a measurement (what the PD sees, the motors'
    friction argument θ̇ / smoothing, the feed-forward). Each episode's measurements follow
    `window` rows measured at rest, so the last window + 1 of them are one contiguous vector and
    the command is one more product. Each tick applies the command computed `delay` ticks ago
    (the first until then: the robot was already holding it) and the motors' Coulomb friction
    from this tick's velocities."""
    first = stack[0]
    count, ticks = len(stack), max(episode.ticks for episode in stack)
    nx, nu = first.plant.model.nq + first.plant.model.nv, first.plant.model.nu
    n = first.plant.joints
    assert first.measure is not None
    width, window, delay = len(first.measure), first.window, first.plant.spec.delay
    measure = np.stack([episode.measure for episode in stack])  # (B, width, nx + 2n)
    law = np.stack([episode.gains for episode in stack])  # (B, n, width · (window + 1))
    rows = np.zeros((ticks, count, nx + 2 * n))
    measured = np.zeros((count, window + ticks, width))  # by episode: windows are contiguous
    for index, episode in enumerate(stack):
        rows[: episode.ticks, index] = episode.term
        measured[index, :window] = episode.rest
    item = measured.itemsize
    recent = np.lib.stride_tricks.as_strided(
        measured,
        shape=(ticks, count, width * (window + 1), 1),
        strides=(width * item, measured.strides[0], item, item),
    )
    commands, flanges = np.empty((ticks, count, n)), np.empty((ticks, count, 3))
    worlds = _Worlds(stack)
    sensed, site = worlds.sensed, worlds.site
    applied = worlds.drive[:, :nu]
    friction = first.opposing is not None
    opposing = np.stack([episode.opposing for episode in stack]) if friction else None
    motor_force = worlds.drive[:, nu:][:, first.plant.motor_dof_slice]
    fri = first.fri
    if fri:  # the robot adds its gravity model at the measured angles to the command, clamped
        units = np.array([[episode.unit] for episode in stack])
        limits = np.stack([episode.plant.torque_limits for episode in stack])
        lowest = -limits
        gravity = ArmsGravity([episode.plant.spec for episode in stack])
        compensations = np.empty((ticks, count, n))
    # Views by tick: rows' state columns, rows and measurements as columns, the angles, θ̇ / s.
    states, row_columns = rows[:, :, :nx], rows[:, :, :, None]
    ahead = measured[:, window:].swapaxes(0, 1)  # (ticks, B, width), no copy
    measurements, angles, rates = ahead[:, :, :, None], ahead[:, :, :n], ahead[:, :, first.slip]
    command_columns = commands[:, :, :, None]
    matmul, multiply, rint, tanh, copy = np.matmul, np.multiply, np.rint, np.tanh, np.copyto
    cap, floor, add = np.minimum, np.maximum, np.add  # np.clip as two ufuncs, without its wrappers
    quantised = first.quantised
    with np.errstate(all="ignore"):  # a diverging world computes on until its block ends
        for start, stop, live in _segments(stack, states):
            for k in range(start, stop):
                copy(states[k], sensed)
                matmul(measure, row_columns[k], out=measurements[k])
                if quantised:
                    rint(angles[k], out=angles[k])
                matmul(law, recent[k], out=command_columns[k])
                if fri:
                    multiply(angles[k], units, out=gravity.angles)
                    gravity.compute()
                    copy(compensations[k], gravity.torque)
                    cap(commands[k - delay if k > delay else 0], limits, out=applied)
                    floor(applied, lowest, out=applied)
                    add(applied, gravity.torque, out=applied)
                else:
                    copy(applied, commands[k - delay if k > delay else 0])
                if friction:
                    rate = rates[k]
                    tanh(rate, out=rate)
                    multiply(rate, opposing, out=motor_force)
                copy(flanges[k], site)
                worlds.step(live)
    for index, episode in enumerate(stack):
        episode.state = states[:, index]
        episode.command, episode.flange = commands[:, index], flanges[:, index]
        episode.measured = measured[index]
        if fri:
            episode.compensation = compensations[:, index]


# --- one episode -------------------------------------------------------------------------------
# The same arithmetic on one episode's rows (np.dot is matmul's product for one episode, bit for
# bit), with the fewest calls a tick can make.


def _exact_alone(episode: Stepped) -> None:
    plant, ticks = episode.plant, episode.ticks
    model, data = plant.model, plant.data
    nx, n = model.nq + model.nv, plant.joints
    states, commands, flanges = (np.empty((ticks, width)) for width in (nx, n, 3))
    ctrl, site = data.ctrl, data.site_xpos[plant.flange]
    feedback = np.empty(n)
    sense, step = mujoco.mj_getState, mujoco.mj_step
    dot, subtract, copy = np.dot, np.subtract, np.copyto
    gains, remaining = episode.gains, plant.substeps - 1
    for start, stop in _blocks(episode):
        block = zip(
            states[start:stop],
            commands[start:stop],
            flanges[start:stop],
            episode.term[start:stop],
            strict=True,
        )
        for state, command, flange, term in block:
            sense(model, data, state, _STATE)
            dot(gains, state, out=feedback)
            subtract(term, feedback, out=ctrl)
            copy(command, ctrl)
            step(model, data)
            copy(flange, site)
            if remaining:
                step(model, data, remaining)
        if _ended(episode, states, start, stop):
            break
    episode.state, episode.command, episode.flange = states, commands, flanges


def _sensed_alone(episode: Stepped) -> None:
    plant, ticks, window = episode.plant, episode.ticks, episode.window
    model, data = plant.model, plant.data
    nx, n = model.nq + model.nv, plant.joints
    assert episode.measure is not None
    width = len(episode.measure)
    rows = episode.term
    measured = np.empty((window + ticks, width))
    measured[:window] = episode.rest
    flat = measured.reshape(-1)
    recent = np.lib.stride_tricks.as_strided(
        flat,
        shape=(ticks, width * (window + 1)),
        strides=(width * flat.itemsize, flat.itemsize),
    )
    commands, flanges = np.empty((ticks, n)), np.empty((ticks, 3))
    delayed = [commands[max(k - plant.spec.delay, 0)] for k in range(ticks)]
    ctrl, site = data.ctrl, data.site_xpos[plant.flange]
    motor_force = data.qfrc_applied[plant.motor_dof_slice]  # a view: writes land in MuJoCo
    opposing = episode.opposing
    sense, step = mujoco.mj_getState, mujoco.mj_step
    dot, multiply, copy, rint, tanh = np.dot, np.multiply, np.copyto, np.rint, np.tanh
    measure, law, quantised = episode.measure, episode.gains, episode.quantised
    remaining = plant.substeps - 1
    states = rows[:, :nx]
    measurements = measured[window:]
    angles, rates = measurements[:, :n], measurements[:, episode.slip]
    gravity = RobotGravity(plant.spec) if episode.fri else None
    unit, limits = episode.unit, plant.torque_limits
    compensations = np.empty((ticks, n)) if gravity is not None else commands  # unused if not
    clip, add = np.clip, np.add
    for start, stop in _blocks(episode):
        block = zip(
            states[start:stop],
            rows[start:stop],
            measurements[start:stop],
            angles[start:stop],
            rates[start:stop],
            recent[start:stop],
            commands[start:stop],
            delayed[start:stop],
            flanges[start:stop],
            compensations[start:stop],
            strict=True,
        )
        for (
            state,
            row,
            measurement,
            angle,
            rate,
            window_now,
            command,
            applied,
            flange,
            added,
        ) in block:
            sense(model, data, state, _STATE)
            dot(measure, row, out=measurement)
            if quantised:
                rint(angle, out=angle)
            dot(law, window_now, out=command)
            if gravity is not None:
                multiply(angle, unit, out=gravity.angles)
                gravity.torque(added)
                clip(applied, -limits, limits, out=ctrl)
                add(ctrl, added, out=ctrl)
            else:
                copy(ctrl, applied)
            if opposing is not None:
                tanh(rate, out=rate)
                multiply(rate, opposing, out=motor_force)
            step(model, data)
            copy(flange, site)
            if remaining:
                step(model, data, remaining)
        if _ended(episode, states, start, stop):
            break
    episode.state, episode.command, episode.flange = states, commands, flanges
    episode.measured = measured
    if gravity is not None:
        episode.compensation = compensations


def _blocks(episode: Stepped) -> Iterator[tuple[int, int]]:
    """(start, stop) of the blocks of ticks between two divergence checks."""
    for start in range(0, episode.ticks, CHECK_EVERY):
        yield start, min(start + CHECK_EVERY, episode.ticks)


def _ended(episode: Stepped, states: np.ndarray, start: int, stop: int) -> bool:
    """Whether the episode diverged in ticks [start, stop), or they were its last; if so, its
    ticks run and why it stopped are set."""
    stopped = _stopped(episode, states, start, stop)
    if stopped is not None:
        episode.ticks_run, episode.divergence = stopped
        return True
    if stop >= episode.ticks:
        episode.ticks_run = episode.ticks
        return True
    return False


def _segments(
    stack: list[Stepped], states: np.ndarray
) -> Iterator[tuple[int, int, np.ndarray | None]]:
    """(start, stop, the worlds still running) over the ticks, between two divergence checks:
    every CHECK_EVERY ticks, and where an episode ends. The worlds are the batch's ids (None:
    all of them). After each, an episode that diverged in it or reached its end leaves the loop
    with its ticks run and why it stopped."""
    live = list(range(len(stack)))
    start = 0
    while live:
        stop = min([start - start % CHECK_EVERY + CHECK_EVERY] + [stack[i].ticks for i in live])
        yield start, stop, None if len(live) == len(stack) else np.array(live, np.int32)
        block = start - start % CHECK_EVERY
        live = [i for i in live if not _ended(stack[i], states[:, i], block, stop)]
        start = stop


def _stopped(episode: Stepped, states: np.ndarray, start: int, stop: int) -> tuple[int, str] | None:
    """(ticks kept, why) if the episode diverged in ticks [start, stop), else None."""
    bad_tick, reason = _first_divergence(
        episode.plant, states[start:stop], episode.reference.q[start:stop]
    )
    if bad_tick is None:
        return None
    tick = start + bad_tick
    return tick, f"{reason} at t = {tick * CONTROL_PERIOD:.3f} s"


def _first_divergence(plant: Plant, state: np.ndarray, q_des: np.ndarray) -> tuple[int | None, str]:
    """First tick of a block where the state is non-finite, out of range or lost, and why."""
    finite = np.isfinite(state).all(axis=1)
    with np.errstate(invalid="ignore"):
        q = state[:, : plant.model.nq] @ plant.link_map.T
        out_of_range = (q < plant.joint_range[:, 0]) | (q > plant.joint_range[:, 1])
        lost = np.abs(q - q_des) > MAX_JOINT_ERROR
    checks = (
        (~finite, "the simulation became non-finite"),
        (out_of_range.any(axis=1), "a joint left its range"),
        (lost.any(axis=1), f"a joint error exceeded {MAX_JOINT_ERROR} rad"),
    )
    first: tuple[int | None, str] = (None, "")
    for flags, reason in checks:
        hits = np.flatnonzero(flags)
        if hits.size and (first[0] is None or hits[0] < first[0]):
            first = (int(hits[0]), reason)
    return first
