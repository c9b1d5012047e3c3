"""The tick loop, for many episodes at once: their control, sensor, delay and friction layers as
arrays over the batch, each world's physics stepped by MuJoCo in compiled code.

An episode's numbers do not depend on the batch it runs in: its arithmetic is the same,
operation for operation, alone or beside others (matrix products are NumPy's stacked `matmul`,
one product per episode; the rest is elementwise), and each world steps on its own MjData. So
an episode's log is byte-identical in any batch (tests/worker/test_stepping.py).

Episodes stack when their arrays have the same shapes and their loops the same steps (a `Kind`);
a batch of mixed kinds runs one stack per kind. A stack splits into `threads` parts, each stepped
by its own thread: MuJoCo releases the GIL while it steps, so the physics of the parts runs on
as many cores while one thread at a time does the (small) array work of its part.

Two loops, as before batching: the first wave's lean one for exact sensors without delay or
friction (the ideal plant, kept bit for bit: PD on the state, `ctrl = reference term − G·state`),
and the one with encoders, a delay and motor friction (`command = P · recent measurements`).
"""

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import mujoco
import numpy as np

from gainfarm.schemas.robot import JOINT_NAMES
from gainfarm.schemas.trajectory import CONTROL_PERIOD
from gainfarm.worker.plant import Plant
from gainfarm.worker.reference import Reference

CHECK_EVERY = 250  # ticks between divergence checks (0.5 s): cheap, and early enough
MAX_JOINT_ERROR = 1.0  # rad: a tracking error this large is a lost arm, not a tuning trade-off
_STATE = mujoco.mjtState.mjSTATE_QPOS | mujoco.mjtState.mjSTATE_QVEL  # what a tick senses
_CTRL = mujoco.mjtState.mjSTATE_CTRL
_DRIVE = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_QFRC_APPLIED
N = len(JOINT_NAMES)


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
    # Filled by the loop:
    ticks_run: int = 0
    divergence: str = ""
    state: np.ndarray = field(default_factory=lambda: np.empty(0))  # (ticks, nx) qpos, qvel
    command: np.ndarray = field(default_factory=lambda: np.empty(0))  # (ticks, 7), unclamped
    flange: np.ndarray = field(default_factory=lambda: np.empty(0))  # (ticks, 3)
    measured: np.ndarray = field(default_factory=lambda: np.empty(0))  # (window + ticks, width)

    @property
    def ticks(self) -> int:
        return len(self.reference.t)

    @property
    def exact(self) -> bool:
        return self.measure is None

    def kind(self) -> tuple:
        """Episodes of one kind stack: the same array shapes, the same steps in the loop."""
        nx = self.plant.model.nq + self.plant.model.nv
        if self.exact:
            return ("exact", nx)
        assert self.measure is not None
        return (
            "sensed",
            nx,
            self.measure.shape,
            self.window,
            self.quantised,
            self.slip.indices(self.measure.shape[0]),  # slices are unhashable before 3.12
            self.opposing is not None,
            self.plant.motor_dof_slice.indices(self.plant.model.nv),
        )


def step_all(episodes: Sequence[Stepped], threads: int = 1) -> None:
    """Run every episode's tick loop; each gets its log arrays, ticks run and divergence."""
    parts: list[list[Stepped]] = []
    kinds: dict[tuple, list[Stepped]] = {}
    for episode in episodes:
        kinds.setdefault(episode.kind(), []).append(episode)
    for stack in kinds.values():
        share = -(-len(stack) // max(1, threads))
        parts.extend(stack[start : start + share] for start in range(0, len(stack), share))
    if threads <= 1 or len(parts) == 1:
        for part in parts:
            _loop(part)
        return
    with ThreadPoolExecutor(min(threads, len(parts))) as pool:
        for done in [pool.submit(_loop, part) for part in parts]:
            done.result()


def _loop(stack: list[Stepped]) -> None:
    (_exact_loop if stack[0].exact else _sensed_loop)(stack)


@dataclass
class _World:
    """One episode's handles for the per-world steps of a tick."""

    index: int
    episode: Stepped
    model: mujoco.MjModel
    data: mujoco.MjData
    sensed: np.ndarray  # its row of the batch's state this tick
    drive: np.ndarray  # what it applies this tick: ctrl (and qfrc_applied)
    flange: np.ndarray  # its row of the batch's flange positions this tick
    site: np.ndarray  # MuJoCo's flange position, live
    remaining: int  # physics steps after the first in a tick


def _worlds(stack: list[Stepped], sensed: np.ndarray, drive: np.ndarray, flange: np.ndarray):
    worlds = []
    for index, episode in enumerate(stack):
        plant = episode.plant
        worlds.append(
            _World(
                index,
                episode,
                plant.model,
                plant.data,
                sensed[index],
                drive[index],
                flange[index],
                plant.data.site_xpos[plant.flange],
                plant.substeps - 1,
            )
        )
    return worlds


def _tick_worlds(worlds: list[_World], signature: int) -> Callable[[], None]:
    """The per-world part of a tick: apply the drive, step (logging the flange where this
    tick's kinematics left it, before the remaining substeps move it), sense the next state."""
    sense, apply, step, copy = mujoco.mj_getState, mujoco.mj_setState, mujoco.mj_step, np.copyto
    rows = [(w.model, w.data, w.sensed, w.drive, w.flange, w.site, w.remaining) for w in worlds]

    def run() -> None:
        for model, data, sensed, drive, flange, site, remaining in rows:
            apply(model, data, drive, signature)
            step(model, data)
            copy(flange, site)
            if remaining:
                step(model, data, remaining)
            sense(model, data, sensed, _STATE)

    return run


def _exact_loop(stack: list[Stepped]) -> None:
    """Exact sensors, no delay, no friction: ctrl = reference term − G · (qpos, qvel).

    MuJoCo clamps each command to the motor's ctrlrange when applying it; the log keeps it
    unclamped, and the episode clamps it in bulk, exactly as MuJoCo did."""
    count, ticks = len(stack), max(episode.ticks for episode in stack)
    nx = stack[0].plant.model.nq + stack[0].plant.model.nv
    gains = np.stack([episode.gains for episode in stack])  # (B, 7, nx)
    term = np.zeros((count, ticks, N))
    for index, episode in enumerate(stack):
        term[index, : episode.ticks] = episode.term
    states, commands, flanges = (np.empty((count, ticks, width)) for width in (nx, N, 3))
    sensed, flange = np.empty((count, nx)), np.empty((count, 3))
    command = np.empty((count, N))  # this tick's: the drive of every world
    feedback = np.empty((count, N, 1))
    worlds = _worlds(stack, sensed, command, flange)
    for world in worlds:
        mujoco.mj_getState(world.model, world.data, world.sensed, _STATE)
    matmul, subtract = np.matmul, np.subtract
    column = sensed[:, :, None]
    with np.errstate(all="ignore"):  # a diverging world computes on until its block ends
        for start, stop, live in _segments(worlds, states):
            tick = _tick_worlds(live, _CTRL)
            for k in range(start, stop):
                matmul(gains, column, out=feedback)
                subtract(term[:, k], feedback[:, :, 0], out=command)
                states[:, k] = sensed
                commands[:, k] = command
                tick()
                flanges[:, k] = flange
    for index, episode in enumerate(stack):
        episode.state, episode.command = states[index], commands[index]
        episode.flange = flanges[index]


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
    nx = first.plant.model.nq + first.plant.model.nv
    nu, nv = first.plant.model.nu, first.plant.model.nv
    assert first.measure is not None
    width, window = len(first.measure), first.window
    measure = np.stack([episode.measure for episode in stack])  # (B, width, nx + 14)
    law = np.stack([episode.gains for episode in stack])  # (B, 7, width · (window + 1))
    rows = np.zeros((count, ticks, nx + 2 * N))
    measured = np.zeros((count, window + ticks, width))
    for index, episode in enumerate(stack):
        rows[index, : episode.ticks] = episode.term
        measured[index, :window] = episode.rest
    item = measured.itemsize
    recent = np.lib.stride_tricks.as_strided(
        measured,
        shape=(count, ticks, width * (window + 1), 1),
        strides=(measured.strides[0], width * item, item, item),
    )
    commands, flanges = np.empty((count, ticks, N)), np.empty((count, ticks, 3))
    delays = np.array([episode.plant.spec.delay for episode in stack])
    everyone = np.arange(count)
    friction = first.opposing is not None
    opposing = np.stack([episode.opposing for episode in stack]) if friction else None
    sensed, flange = np.empty((count, nx)), np.empty((count, 3))
    drive = np.zeros((count, nu + (nv if friction else 0)))
    applied = drive[:, :nu]
    motor_force = drive[:, nu:][:, first.plant.motor_dof_slice] if friction else None
    measurement, command = np.empty((count, width, 1)), np.empty((count, N, 1))
    worlds = _worlds(stack, sensed, drive, flange)
    for world in worlds:
        mujoco.mj_getState(world.model, world.data, world.sensed, _STATE)
    matmul, multiply, rint, tanh = np.matmul, np.multiply, np.rint, np.tanh
    angles, slip = slice(0, N), first.slip
    states = rows[:, :, :nx]
    with np.errstate(all="ignore"):  # a diverging world computes on until its block ends
        for start, stop, live in _segments(worlds, states):
            tick = _tick_worlds(live, _DRIVE if friction else _CTRL)
            for k in range(start, stop):
                states[:, k] = sensed
                matmul(measure, rows[:, k, :, None], out=measurement)
                now = measured[:, window + k]
                now[:] = measurement[:, :, 0]
                if first.quantised:
                    rint(now[:, angles], out=now[:, angles])
                matmul(law, recent[:, k], out=command)
                commands[:, k] = command[:, :, 0]
                applied[:] = commands[everyone, np.maximum(k - delays, 0)]
                if friction:
                    rate = now[:, slip]
                    tanh(rate, out=rate)
                    multiply(rate, opposing, out=motor_force)
                tick()
                flanges[:, k] = flange
    for index, episode in enumerate(stack):
        episode.state = states[index]
        episode.command, episode.flange = commands[index], flanges[index]
        episode.measured = measured[index]


def _segments(worlds: list[_World], states: np.ndarray) -> Iterator[tuple[int, int, list[_World]]]:
    """(start, stop, worlds still running) over the ticks, between two divergence checks: every
    CHECK_EVERY ticks, and where an episode ends. After each, an episode that diverged in it or
    reached its end leaves the loop with its ticks run and why it stopped."""
    live = list(worlds)
    start = 0
    while live:
        stop = min([start - start % CHECK_EVERY + CHECK_EVERY] + [w.episode.ticks for w in live])
        yield start, stop, live
        still = []
        for world in live:
            episode = world.episode
            block = start - start % CHECK_EVERY
            stopped = _stopped(episode, states[world.index], block, stop)
            if stopped is not None:
                episode.ticks_run, episode.divergence = stopped
            elif stop >= episode.ticks:
                episode.ticks_run = episode.ticks
            else:
                still.append(world)
        live = still
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
