"""`analytic start` once it runs: every option checked, the cheapest first, before anything heavy
loads (a refused option costs little more than `import click`); then a local farm started, the
run made as `tune` makes it, and its progress on the terminal (work/tuning.py)."""

import contextlib
from collections.abc import Iterator
from pathlib import Path

from gainfarm import plugins
from gainfarm.analytic.commands.work.common import (
    centre,
    check_farm,
    make_config,
    on_the_robot,
    plants_from,
    robot_plant,
)
from gainfarm.analytic.evaluators.local import LocalFarm
from gainfarm.analytic.tuning import defaults
from gainfarm.analytic.tuning.algorithms import STEADY_STATE, steady_state_refusal
from gainfarm.analytic.tuning.records import CONFIG_JSON
from gainfarm.cli import options, values
from gainfarm.cli.app import CliError
from gainfarm.schemas.trajectory import TrajectorySpec

STANDARD = TrajectorySpec.model_fields["duration"].default  # a trajectory's, before the robot's


def start(
    pop: int,
    kinds: tuple[str, ...],
    duration: float | None,
    trajectory_seed: int,
    center: str | None,
    size: float,
    seed: int,
    generations: int | None,
    evaluations: int | None,
    robot: str,
    joints: str,
    plant: str,
    payload: float | None,
    payload_com: tuple[float, ...] | None,
    feedforward: Path | None,
    limits_file: Path | None,
    min_damping: float | None,
    plants: int,
    aggregate: str,
    check_plants: int,
    uncertainty_file: Path | None,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int | None,
    out: Path | None,
    keep: str,
    asynchronous: bool,
    algorithm: str,
    first_population: str,
    torque_measure: str,
    objective_names: tuple[str, ...],
    objective_scaling: str,
    replicate: bool,
    spot_checks: float | None,
    balance: bool,
) -> None:
    """`analytic start` with its options as parsed (analytic/commands/start.py); `center` and
    `duration` None: the robot's workspace centre and each kind's default duration on it."""
    options.check_load(payload, payload_com)
    objectives = _objectives(objective_names, torque_measure)
    identity = check_farm(connect, local, tls, participant)
    limits = values.limits_from(limits_file, min_damping)
    if asynchronous and algorithm not in STEADY_STATE:  # before the robot's module loads MuJoCo
        raise CliError(f"--async: {steady_state_refusal(algorithm)}")
    nominal = values.with_load(robot_plant(plant, joints, robot), payload, payload_com, plant)
    where = centre(center, nominal.robot)
    given = values.trajectories(
        kinds, STANDARD if duration is None else duration, trajectory_seed, where, size
    )
    trajectories = on_the_robot(given, duration, nominal.robot)
    if out is not None and (out / CONFIG_JSON).exists():  # `tune` would resume it: a start does not
        raise CliError(f"--out: {str(out)!r} already holds a run; resume it or choose another")
    fields = {
        "pop": pop,
        "seed": seed,
        "trajectories": trajectories,
        "plant": nominal,
        "aggregate": aggregate,
        "limits": limits,
        "generations": generations,
        "evaluations": evaluations,
        "keep": keep,
        "asynchronous": asynchronous,
        "algorithm": algorithm,
        "objectives": objectives,
        "from_defaults": first_population == "defaults",
        "objective_scaling": objective_scaling,
        "replicate": replicate,
        "spot_checks": spot_checks,
        "balance": balance,
    }
    make_config(fields)  # what the config alone refuses, before the variants load MuJoCo
    learned = values.feedforward_model(feedforward, nominal.robot)
    with _farm(connect, workers, nominal.robot) as farm:
        # start-up: MuJoCo, Zenoh, pymoo and rich load once the options are checked (but the
        # variants', which need MuJoCo), while the local farm starts
        from gainfarm.analytic.commands.work import tuning
        from gainfarm.analytic.compose import defaults_hold

        tuning.followable(trajectories, robot=nominal.robot)  # before a corner's episodes run
        holds = defaults_hold(trajectories, limits, objectives)
        fields["plants"] = plants_from(
            plants, uncertainty_file, nominal, seed, plant=plant, designed=True, holds=holds
        )
        fields["check_plants"] = plants_from(
            check_plants, uncertainty_file, nominal, seed, held_out=True, plant=plant
        )
        where = tuning.FarmOptions(connect, workers, identity, farm)
        tuning.start_run(fields, out, learned[0] if learned else None, where)


def _objectives(names: tuple[str, ...], torque_measure: str) -> tuple[str, str]:
    """The run's objectives: the two --objective names, checked here before anything heavy is
    imported, or f_acc and the --torque-measure's."""
    if not names:
        return ("f_acc", defaults.TORQUE_MEASURES[torque_measure])
    if len(names) != 2:
        raise CliError(f"--objective: name two objectives, in order (given {len(names)})")
    if names[0] == names[1]:
        raise CliError(f"--objective: {names[0]!r} twice; name two different ones")
    try:
        for name in names:
            plugins.check_name(plugins.OBJECTIVES, name)
    except plugins.PluginError as error:
        raise CliError(f"--objective: {error}") from None
    return (names[0], names[1])


@contextlib.contextmanager
def _farm(
    connect: tuple[str, ...], workers: int | None, robot: str
) -> "Iterator[LocalFarm | None]":
    """Without --connect, a local farm started before the heavy imports: its processes start
    while this one imports and checks the run (a second or two), so it serves by the time the
    first jobs are ready. `tune` stops it when done with it; this block, if `tune` never used it
    (a refused variant, a run directory taken)."""
    if connect:
        yield None
        return
    with LocalFarm(workers, robot=robot) as farm:
        yield farm
