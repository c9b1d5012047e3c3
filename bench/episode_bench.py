"""Cost of an episode, of its log and of the worker's whole job, against the episode's own
physics, alone and in batches; and of scoring a log from its bytes.

    python bench/episode_bench.py [--quick] [--repeats 5] [--duration 5] [--batches 1,8,32,128]
                                  [--robots iiwa14,ur5e,...]

The anchor is the physics the episode ran: its per-step `ctrl` and `qfrc_applied` (the motors'
commands, their friction), recorded as the episode stepped, replayed through MuJoCo's own
`rollout` from the episode's first state (mj_step in C, one thread, no Python per step). The
replay must retrace the episode (its link angles at the last tick within 0.01 rad of the log's):
then it is the cost of the same physics and nothing else. Each case is a ratio to it ("x
physics"), per episode, in process CPU time: an episode alone (`run_episode`), with its MCAP
bytes, the worker's whole job (episode + MCAP + scores: `job.simulate`); then episodes and jobs
stepped together (`simulate_all`, `simulate_batch`) in batches of each size, on one thread, each
episode a candidate of its own (the default gains times 0.8-1.2); then the largest batch on
every core, in wall time per episode. Each case is timed in interleaved repeats in one run and
the fastest repeat taken (the cost of the work itself; the shared machine only ever adds), so
that the ratios compare like with like; the medians are printed beside it.

Then the same per arm (`--robots`, every installed one by default), each on its own spiral at
its workspace centre with its own default gains, on its own realistic plant: its physics
replayed, an episode alone and episodes in a batch (the largest of --batches up to 32), each a
ratio to that arm's own physics, and the batch's ratio against the iiwa 14's (issue 49's target:
within 10 %). All arms in one run, their repeats interleaved.
"""

import os
import random
import statistics
import time
from collections.abc import Callable

import click
import mujoco
import numpy as np
from common import print_table
from mujoco import rollout

from gainfarm import plugins
from gainfarm.models import plant_preset, robot_of
from gainfarm.models.urdf import description
from gainfarm.schemas import EpisodeSpec, PDGains, TrajectorySpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.mcap_episode import decode_episode, episode_bytes
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import DEFAULT_ROBOT, IDEAL_PLANT, REALISTIC_PLANT
from gainfarm.worker.episode import Prepared, compensation, run_episode, simulate_all
from gainfarm.worker.job import simulate, simulate_batch
from gainfarm.worker.plant import Plant
from gainfarm.worker.reference import reference_for

REPLAY_TOLERANCE = 0.01  # rad: the replayed arm must end where the episode's did
_DRIVE = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_QFRC_APPLIED


def recorded_physics(spec: EpisodeSpec) -> tuple[EpisodeLog, np.ndarray]:
    """The episode's log, and what it drove its physics with: (ctrl, qfrc_applied) per step."""
    drives: list[np.ndarray] = []
    step = mujoco.mj_step

    def recording(model: mujoco.MjModel, data: mujoco.MjData, nstep: int = 1) -> None:
        for _ in range(nstep):
            drives.append(np.concatenate([data.ctrl, data.qfrc_applied]))
            step(model, data)

    mujoco.mj_step = recording  # the tick loop looks mj_step up as it starts
    try:
        log = run_episode(spec)
    finally:
        mujoco.mj_step = step
    return log, np.array(drives)


def physics(spec: EpisodeSpec) -> Callable[[], None]:
    """The episode's physics replayed in C; checked to retrace the episode first."""
    log, drives = recorded_physics(spec)
    plant = Plant(spec.plant)
    plant.reset(reference_for(spec.trajectory, spec.plant.robot).q[0])
    signature = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.empty(mujoco.mj_stateSize(plant.model, signature))
    mujoco.mj_getState(plant.model, plant.data, initial, signature)

    # Written in place, every replay: the physics, not the first touch of fresh output pages.
    states = np.empty((1, len(drives), len(initial)))
    sensors = np.empty((1, len(drives), plant.model.nsensordata))

    def replay() -> np.ndarray:
        rollout.rollout(
            plant.model,
            plant.data,
            initial,
            drives,
            control_spec=_DRIVE,
            state=states,
            sensordata=sensors,
        )
        return states[0]

    replay()
    last_tick = (log.metadata.ticks_run - 1) * plant.substeps - 1  # state at the last tick
    qpos = states[0, last_tick, 1 : 1 + plant.model.nq]  # after the time
    miss = np.abs(plant.link_map @ qpos - log.q[-1]).max()
    if not miss < REPLAY_TOLERANCE:
        raise SystemExit(f"the replay does not retrace the episode: {miss:.3g} rad off")
    return replay


def candidates(spec: EpisodeSpec, count: int, seed: int = 0) -> list[EpisodeSpec]:
    """`count` episodes of `spec`'s path and plant, each a candidate of its own: its gains times
    0.8-1.2, joint by joint (the iiwa's as they always were: its kp's factors, then its kd's)."""
    rng = random.Random(seed)
    gains = spec.gains

    def scaled(values: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(value * rng.uniform(0.8, 1.2) for value in values)

    return [
        spec.model_copy(update={"gains": PDGains(kp=scaled(gains.kp), kd=scaled(gains.kd))})
        for _ in range(count)
    ]


def prepared(specs: list[EpisodeSpec]) -> list[Prepared]:
    out = []
    for spec in specs:
        reference = reference_for(spec.trajectory, spec.plant.robot)
        out.append((spec, reference, compensation(spec, reference)))
    return out


def _batches(text: str) -> list[int]:
    try:
        sizes = [int(part) for part in text.split(",")]
    except ValueError:
        raise click.BadParameter("comma-separated batch sizes, e.g. 1,8,32") from None
    if not sizes or min(sizes) < 1:
        raise click.BadParameter("batch sizes are at least 1")
    return sizes


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--quick", is_flag=True, help="a CI-sized run: 1 s episodes, batches 1,8, 2 repeats")
@click.option("--repeats", type=click.IntRange(min=1), default=5, show_default=True)
@click.option(
    "--duration",
    type=click.FloatRange(min=0, min_open=True),
    default=5.0,
    show_default=True,
    help="s per episode",
)
@click.option("--batches", default="1,8,32,128", show_default=True, help="batch sizes")
@click.option(
    "--robots",
    help="the arms of the per-arm table, comma-separated  [default: every installed one]",
)
def main(quick: bool, repeats: int, duration: float, batches: str, robots: str | None) -> None:
    sizes = _batches(batches)
    arms = _robots(robots)
    if quick:
        repeats, duration, sizes = 2, 1.0, [1, 8]
    kind = "fourier" if duration < 3 else "spiral"  # a Cartesian path needs some 3 s
    trajectory = TrajectorySpec(kind=kind, duration=duration)
    realistic = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=trajectory, plant=REALISTIC_PLANT)
    ideal = realistic.model_copy(update={"plant": IDEAL_PLANT})
    reference_for(trajectory)  # the IK runs once per trajectory: not per-episode cost
    cores = len(os.sched_getaffinity(0))
    largest = max(sizes)
    batch_specs = {size: candidates(realistic, size) for size in sizes}
    batch_episodes = {size: prepared(specs) for size, specs in batch_specs.items()}
    logged = episode_bytes(run_episode(realistic), description())

    cases: dict[str, tuple[Callable[[], object], int]] = {  # what, episodes it runs
        "physics (replayed in C)": (physics(realistic), 1),
        "ideal episode": (lambda: run_episode(ideal), 1),
        "realistic episode": (lambda: run_episode(realistic), 1),
        "realistic episode + MCAP": (
            lambda: episode_bytes(run_episode(realistic), description()),
            1,
        ),
        "whole job (episode + MCAP + scores)": (lambda: simulate(realistic), 1),
        "scores from the MCAP bytes (the analytic's check)": (
            lambda: score(decode_episode(logged)),
            1,
        ),
    }
    for size in sizes:
        episodes, specs = batch_episodes[size], batch_specs[size]
        cases[f"episodes, batch of {size}"] = (lambda e=episodes: simulate_all(e), size)
        cases[f"jobs, batch of {size}"] = (lambda s=specs: simulate_batch(s), size)
    threaded = f"jobs, batch of {largest} on {cores} threads (wall)"
    cases[threaded] = (lambda: simulate_batch(batch_specs[largest], threads=cores), largest)

    times: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, (case, count) in cases.items():
            clock = time.perf_counter if name == threaded else time.process_time
            start = clock()
            case()
            times[name].append((clock() - start) / count)

    fastest = {name: min(values) for name, values in times.items()}
    median = {name: statistics.median(values) for name, values in times.items()}
    anchor, middle = fastest["physics (replayed in C)"], median["physics (replayed in C)"]
    plant = realistic.plant
    print(
        f"{duration:g} s {kind} episode, {trajectory.ticks} ticks, {plant.joints} joints, "
        f"{plant.substeps} physics steps per tick; CPU time per episode (the threaded case: "
        f"wall), the fastest of {repeats} (median beside)\n"
    )
    print_table(
        ("case", "ms per episode", "x physics", "median ms", "median x physics"),
        "lrrrr",
        (
            (name, f"{t * 1000:.2f}", f"{t / anchor:.2f}", f"{m * 1000:.2f}", f"{m / middle:.2f}")
            for (name, t), m in zip(fastest.items(), median.values(), strict=True)
        ),
    )
    batch = max((size for size in sizes if size <= 32), default=largest)  # the targets' size
    print()
    for name, target in (
        ("realistic episode", 1.6),
        (f"episodes, batch of {batch}", 1.15 if batch == 32 else None),
        (f"jobs, batch of {batch}", 1.3 if batch == 32 else None),
    ):
        aim = "" if target is None else f" (target <= {target})"
        print(f"{name}: {fastest[name] / anchor:.2f}x physics{aim}")
    whole = fastest[f"jobs, batch of {batch}"]
    print(f"real-time factor, one thread (jobs, batch of {batch}): {duration / whole:.0f}x")
    print(f"bytes per episode: {len(logged):,}")
    print()
    per_arm(arms, repeats, duration, batch)


def _robots(text: str | None) -> list[str]:
    """--robots' arms (the iiwa 14 first: the others are compared with it), each installed."""
    names = plugins.names(plugins.ROBOTS) if text is None else tuple(text.split(","))
    for name in names:
        try:
            robot_of(name)
        except plugins.PluginError as error:
            raise click.BadParameter(str(error), param_hint="'--robots'") from None
    return [DEFAULT_ROBOT, *(name for name in names if name != DEFAULT_ROBOT)]


def arm_episode(robot: str, duration: float) -> EpisodeSpec:
    """An arm's episode as the per-arm table runs it: its spiral (the fourier kind, shorter than
    a Cartesian path can be) at its workspace centre, its default gains, its realistic plant."""
    arm = robot_of(robot)
    kind = "fourier" if duration < 3 else "spiral"
    trajectory = TrajectorySpec(kind=kind, duration=duration, center=arm.workspace.center)
    return EpisodeSpec(
        gains=arm.default_gains, trajectory=trajectory, plant=plant_preset("realistic", robot)
    )


def per_arm(robots: list[str], repeats: int, duration: float, batch: int) -> None:
    """Each arm's episode, alone and in a batch, against its own physics; the batch's ratio
    against the iiwa 14's. All arms' cases interleaved in each repeat."""
    cases: dict[tuple[str, str], tuple[Callable[[], object], int]] = {}
    plants = {}
    for robot in robots:
        spec = arm_episode(robot, duration)
        plants[robot] = _substeps(spec)
        episodes = prepared(candidates(spec, batch))
        cases[robot, "physics"] = (physics(spec), 1)
        cases[robot, "alone"] = (lambda s=spec: run_episode(s), 1)
        cases[robot, "batch"] = (lambda e=episodes: simulate_all(e), batch)
    times: dict[tuple[str, str], list[float]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, (case, count) in cases.items():
            start = time.process_time()
            case()
            times[name].append((time.process_time() - start) / count)
    fastest = {name: min(values) for name, values in times.items()}
    ratio = {robot: fastest[robot, "batch"] / fastest[robot, "physics"] for robot in robots}
    print(
        f"per arm: its {duration:g} s path at its workspace centre, its default gains, its "
        f"realistic plant; CPU time per episode, the fastest of {repeats}\n"
    )
    print_table(
        (
            "arm",
            "joints",
            "physics steps per tick",
            "physics ms",
            "episode alone x physics",
            f"batch of {batch} x physics",
            "against the iiwa 14's",
        ),
        "lrrrrrr",
        (
            (
                robot,
                str(len(robot_of(robot).joint_names)),
                str(plants[robot]),
                f"{fastest[robot, 'physics'] * 1000:.2f}",
                f"{fastest[robot, 'alone'] / fastest[robot, 'physics']:.2f}",
                f"{ratio[robot]:.2f}",
                f"{ratio[robot] / ratio[DEFAULT_ROBOT]:.2f}",
            )
            for robot in robots
        ),
    )
    worst = max(abs(ratio[robot] / ratio[DEFAULT_ROBOT] - 1) for robot in robots)
    print(f"\nthe farthest arm's batch ratio from the iiwa 14's: {worst:.0%} (target <= 10 %)")


def _substeps(spec: EpisodeSpec) -> int:
    """The physics steps a tick of the spec's plant takes (its robot's resolved plant's)."""
    return Plant(spec.plant).substeps


if __name__ == "__main__":
    main()
