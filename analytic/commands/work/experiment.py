"""`analytic experiment NAME` once it runs (analytic/commands/experiment.py declares it): the
experiment's options checked, then its runs on the farm with their progress on the terminal."""

from pathlib import Path

import click
from pydantic import ValidationError
from rich.console import Console

from gainfarm.analytic.commands.shared import farm_problem, refuse_under_a_file, unwritable
from gainfarm.analytic.commands.work.common import check_farm, config_problem, robot_plant
from gainfarm.analytic.commands.work.tuning import followable, own_farm, study_name
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.experiments.registry import ExperimentSpec
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import RunBusy
from gainfarm.analytic.view.progress import Display
from gainfarm.cli import interrupts, options
from gainfarm.cli.app import CliError
from gainfarm.cli.values import limits_from, with_load
from gainfarm.models import robot_of
from gainfarm.schemas.trajectory import TrajectorySpec

# Without a terminal, an experiment's progress is a plain line this often at most: its runs go
# on side by side, each a line per evaluation.
EXPERIMENT_LOG_SECONDS = 10.0


def run(
    spec: ExperimentSpec,
    reps: int,
    pop: int,
    robot: str,
    plant: str,
    generations: int | None,
    evaluations: int | None,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int | None,
    parallel_runs: int | None,
    out: Path,
    duration: float | None = None,
    limits_file: Path | None = None,
    payload: float | None = None,
    payload_com: tuple[float, ...] | None = None,
    **given: str | None,
) -> None:
    """Check everything the experiment needs before anything runs, then run it on the farm."""
    options.check_load(payload, payload_com)
    identity = check_farm(connect, local, tls, participant)
    limits = limits_from(limits_file)
    nominal = with_load(robot_plant(plant, None, robot), payload, payload_com, plant)
    refused = spec.refusal(nominal.robot)
    if refused is not None:
        raise CliError(f"--robot: {refused}")
    chosen: dict[str, object] = {}
    for option in spec.options:
        text = given[option.parameter]
        if text is None:  # not given and no default: the experiment's own
            continue
        try:
            chosen[option.parameter] = option.parse(text)
        except ValueError as error:
            raise CliError(f"{option.flag}: {error}") from None
    try:
        centre = robot_of(nominal).workspace.center  # the arm's default trajectory's
        base = RunConfig(
            pop=pop,
            trajectories=(
                TrajectorySpec(center=centre)
                if duration is None
                else TrajectorySpec(duration=duration, center=centre),
            ),
            plant=nominal,
            limits=limits,
            generations=generations,
            evaluations=evaluations,
            keep="front",
        )
        base = spec.prepare(base, chosen)
        trajectories = list(spec.trajectories(base, chosen))
    except ValidationError as error:
        raise CliError(config_problem(error)) from None
    except ValueError as error:
        raise CliError(str(error)) from None
    followable(trajectories, spec.trajectory_option, nominal.robot)
    refuse_under_a_file(out, "--out")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise CliError(f"--out: cannot create {str(out)!r}: {error.strerror}") from None
    console = Console(stderr=True)

    def progress(text: str) -> None:
        """A run's step (called from the runs' threads): the place a Ctrl-C stops them."""
        interrupts.check()
        display.show(text)
        display.every(text, EXPERIMENT_LOG_SECONDS)

    try:
        with (
            own_farm(connect, workers, nominal.robot) as (endpoints, own_workers),
            Display(console, hushed=interrupts.INTERRUPTED.is_set) as display,
        ):
            display.show(spec.name)
            experiment = Experiment(
                out,
                # The experiment's own names for its runs are neither unique nor short enough
                # for farm studies. Experiments keep their fronts' logs alone: fetched from the
                # workers.
                lambda _name, directory: FarmClient(
                    endpoints,
                    study_name(directory, identity),
                    directory,
                    identity=identity,
                    keep_logs=False,
                    trusted=not connect,  # a local farm of this process's own workers
                    own_workers=own_workers,  # ... and none other
                ),
                progress,
                parallel=parallel_runs,
            )
            try:
                spec.run(experiment, base, reps, **chosen)
            except (ValueError, RunBusy) as error:
                raise CliError(str(error)) from None
    except OSError as error:
        if isinstance(error, ConnectionError):
            raise CliError(farm_problem(connect, error)) from None
        raise unwritable(error, "run the same command again to go on") from None
    except KeyboardInterrupt:
        interrupts.stop("analytic", "stopped; run the same command again to go on")
    click.echo(f"{spec.name}: report, figures and results.csv in {out}/", err=True)
