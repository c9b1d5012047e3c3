"""`analytic start`: a tuning run, as `tune` makes it, with its progress on the terminal."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import (
    algorithm_names,
    farm_options,
    pop_option,
    prechecked,
    robustness,
    termination_options,
    unless_default,
)
from gainfarm.analytic.tuning import defaults
from gainfarm.cli import options


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
@options.robot("the arm to tune")
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
def start(**given: Any) -> None:
    """Tune the arm's PD gains (a Kp and a Kd per joint) with NSGA-II (or --algorithm) on the
    farm: maximise accuracy, minimise torque steps.

    Stops after --generations, after --evaluations, or (by default) when the hypervolume has
    stopped growing. Ctrl-C stops cleanly; `analytic resume RUN` goes on.
    """
    # Not given: the robot's workspace centre, and each kind's default duration on it.
    given = unless_default(given, "center", "duration")
    prechecked(given)  # before the work's imports: the contract, MuJoCo, Zenoh, pymoo
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.start import start as work

    work(**given)
