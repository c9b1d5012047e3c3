"""`analytic start`: a tuning run, as `tune` makes it, with its progress on the terminal."""

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import click

from gainfarm import plugins
from gainfarm.analytic.commands.shared import (
    algorithm_names,
    check_farm,
    config_problem,
    farm_options,
    plants_from,
    pop_option,
    robustness,
    run_with_progress,
    start_option,
    termination_options,
)
from gainfarm.analytic.tuning import defaults
from gainfarm.cli import options
from gainfarm.cli.app import CliError

if TYPE_CHECKING:
    from gainfarm.analytic.evaluators.local import LocalFarm


@click.command()
@pop_option()
@options.trajectory(
    multiple=True,
    help="one: a specific controller; several (repeat): a generic one, objectives averaged "
    "(see --balance)",
)
@options.duration()
@options.placement()
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=defaults.SEED,
    show_default=True,
    help="NSGA-II's seed",
)
@termination_options()
@options.joints()
@options.plant()
@options.load()
@options.feedforward(
    help="add a learned inverse-dynamics model's torque for the reference to every episode's "
    "PD and tune the gains on top (a directory from `analytic learn`, or its model.npz)"
)
@options.limits()
@options.min_damping()
@robustness()
@farm_options
@click.option("--out", type=click.Path(path_type=Path), help="run directory  [default: runs/TIME]")
@click.option(
    "--keep",
    type=click.Choice(defaults.KEEPS),
    default=defaults.KEEP,
    show_default=True,
    help="which episode logs to keep: the front's (the workers keep the logs and the front's "
    "are fetched from them), or all (each comes with its result and is kept: about 1.5 MB "
    "per 5 s episode, every evaluation's)",
)
@click.option(
    "--async",
    "asynchronous",
    is_flag=True,
    help="a steady state (NSGA-II's or TPE's): a new candidate as soon as any result returns, "
    "each result told as it comes (TPE learns from every one, not a generation at a time)",
)
@click.option(
    "--algorithm",
    type=options.LazyChoice(algorithm_names),
    default=defaults.ALGORITHM,
    show_default=True,
    help="the optimiser: pymoo's NSGA-II, NSGA-III, SMS-EMOA, MOEA/D, AGE-MOEA-II, Optuna's "
    "TPE, or uniform random sampling (--async: nsga2 or tpe only)",
)
@click.option(
    "--first-population",
    type=click.Choice(("defaults", "random")),
    default="defaults",
    show_default=True,
    help="the optimiser's first population: the default gains and random samples (the run is "
    "judged against them), or random samples alone (pymoo's algorithms; TPE and random "
    "sampling sample as they do)",
)
@click.option(
    "--torque-measure",
    type=click.Choice(tuple(defaults.TORQUE_MEASURES)),
    default=defaults.TORQUE_MEASURE,
    show_default=True,
    help="the second objective: per-joint, each joint's squared torque change weighed by its "
    "torque limit (f_t_joint: the wrist counts), or raw, the paper's f_t (A1, A2 and A4 make "
    "nearly all of it)",
)
@click.option(
    "--objective",
    "objective_names",
    multiple=True,
    metavar="NAME",
    help="an objective, by name (repeat: two, in order; the first is drawn across, the second "
    "up): f_acc, f_t, f_t_joint or an installed plug-in's (gainfarm.objectives); replaces "
    "--torque-measure  [default: f_acc and --torque-measure's]",
)
@click.option(
    "--objective-scaling",
    type=click.Choice(defaults.OBJECTIVE_SCALINGS),
    default=defaults.OBJECTIVE_SCALING,
    show_default=True,
    help="what the optimiser is told: raw objectives, or log: as the hypervolume sees them "
    "(f_t on a log scale); the records stay raw",
)
@click.option(
    "--replicate/--no-replicate",
    default=defaults.REPLICATE,
    show_default=True,
    help="on a farm, validate the front: this process reruns each member's episodes and each "
    "worker's log must agree bit for bit",
)
@click.option(
    "--spot-checks",
    type=click.FloatRange(0, 1),
    default=defaults.SPOT_CHECKS,
    metavar="RATE",
    help="on a farm, with --replicate: the share of every worker's episodes, drawn at random "
    "as they return, that this process also reruns (a worker lying about episodes that never "
    "reach the front is caught too); 0: none. Default: sized as the run starts so that a "
    "worker lying on a tenth of its share of the run's episodes is caught with probability "
    "0.99",
)
@click.option(
    "--balance/--no-balance",
    default=defaults.BALANCE,
    show_default=True,
    help="weigh each trajectory's objectives (generic) and scale each plant's (robust) so "
    "that all count alike at the default gains (simulated here first, one episode per "
    "trajectory and plant), rather than the plain means and worsts, which the roughest "
    "trajectory and the worst plant would dominate",
)
def start(
    pop: int,
    kinds: tuple[str, ...],
    duration: float,
    trajectory_seed: int,
    center: str,
    size: float,
    seed: int,
    generations: int | None,
    evaluations: int | None,
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
    """Tune the 14 PD gains with NSGA-II (or --algorithm) on the farm: maximise accuracy,
    minimise torque steps.

    Stops after --generations, after --evaluations, or (by default) when the hypervolume has
    stopped growing. Ctrl-C stops cleanly; `analytic resume RUN` goes on.
    """
    options.check_load(payload, payload_com)
    objectives = _objectives(objective_names, torque_measure)
    identity = check_farm(connect, local, tls, participant)
    with _farm(connect, workers) as farm:
        from pydantic import ValidationError

        from gainfarm.analytic import compose
        from gainfarm.analytic.tuning.config import RunConfig
        from gainfarm.analytic.tuning.records import CONFIG_JSON
        from gainfarm.analytic.tuning.run import RunBusy

        limits = options.limits_from(limits_file, min_damping)
        trajectories = options.trajectories(kinds, duration, trajectory_seed, center, size)
        learned = options.feedforward_model(feedforward)
        model_file = learned[0] if learned is not None else None
        model = options.with_load(options.model_spec(plant, joints), payload, payload_com, plant)
        variants = plants_from(plants, uncertainty_file, model, seed, plant=plant, designed=True)
        held_out = plants_from(
            check_plants, uncertainty_file, model, seed, held_out=True, plant=plant
        )
        try:
            config = RunConfig(
                pop=pop,
                seed=seed,
                trajectories=trajectories,
                model=model,
                plants=variants,
                check_plants=held_out,
                aggregate=aggregate,
                limits=limits,
                generations=generations,
                evaluations=evaluations,
                keep=keep,
                asynchronous=asynchronous,
                algorithm=algorithm,
                objectives=objectives,
                from_defaults=first_population == "defaults",
                objective_scaling=objective_scaling,
                replicate=replicate,
                spot_checks=spot_checks,
                feedforward=_digest(model_file) if model_file is not None else None,
            )
        except ValidationError as error:
            raise CliError(config_problem(error)) from None
        out = out or compose.new_directory()
        if (out / CONFIG_JSON).exists():  # `tune` would resume it: a start does not
            raise CliError(f"--out: {str(out)!r} already holds a run; resume it or choose another")
        try:
            run_with_progress(
                lambda watch, on_check: compose.tune(
                    config,
                    out,
                    connect=connect,
                    workers=workers,
                    farm=farm,
                    identity=identity,
                    feedforward=model_file,
                    balance=balance,
                    watch=watch,
                    on_check=on_check,
                ),
                out,
                connect,
            )
        except compose.CannotStart as error:
            also = "; give --no-balance" if error.part == "balance" else ""
            raise CliError(f"{start_option(error.part)}: {error}{also}") from None
        except RunBusy as error:
            raise CliError(f"--out: {error}") from None


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
def _farm(connect: tuple[str, ...], workers: int | None) -> "Iterator[LocalFarm | None]":
    """Without --connect, a local farm started before anything else is imported or checked:
    its processes start while this one does that (a second or two), so it serves by the time
    the first jobs are ready. `tune` stops it when done with it; this block, if `tune` never
    used it (a refused option, a run directory taken)."""
    if connect:
        yield None
        return
    from gainfarm.analytic.evaluators.local import LocalFarm

    with LocalFarm(workers) as farm:
        yield farm


def _digest(model_file: bytes) -> str:
    from gainfarm.models.dynamics import digest

    return digest(model_file)
