"""`analytic experiment NAME`: run one of the installed experiments (analytic.experiments).

Each experiment is a subcommand made from its declaration (an `ExperimentSpec`, found by the
entry-point group `gainfarm.experiments`): the options every experiment shares, and its own.
Only the experiment named is imported; an option of another experiment is refused in one line
that says whose it is.
"""

from pathlib import Path
from typing import TYPE_CHECKING

import click

from gainfarm import plugins
from gainfarm.analytic.commands.shared import (
    check_farm,
    config_problem,
    farm_options,
    farm_problem,
    followable,
    own_farm,
    pop_option,
    refuse_under_a_file,
    study_name,
    termination_options,
    unwritable,
)
from gainfarm.cli import interrupts, options
from gainfarm.cli.app import CliError

if TYPE_CHECKING:
    from gainfarm.analytic.experiments.registry import ExperimentSpec

# Without a terminal, an experiment's progress is a plain line this often at most: its runs go
# on side by side, each a line per evaluation.
EXPERIMENT_LOG_SECONDS = 10.0


def _shared_options(duration: float | None) -> list[click.Parameter]:
    """The options every experiment takes (--duration only if its base trajectory has one)."""
    decorators = [
        click.option(
            "--reps",
            type=click.IntRange(min=1),
            default=5,
            show_default=True,
            help="repetitions (seeds 0..reps-1)",
        ),
        pop_option(),
        *(
            [
                click.option(
                    "--duration",
                    type=float,
                    default=duration,
                    show_default=True,
                    help="trajectory duration, s",
                )
            ]
            if duration is not None
            else []
        ),
        options.plant(),
        options.load(),
        options.limits(),
        termination_options(per_run=True),
        farm_options,
        click.option(
            "--parallel-runs",
            type=click.IntRange(min=1),
            help="tuning runs (with their cross-evaluations) at once, each its own study on the "
            "farm  [default: all of the experiment's]",
        ),
        click.option(
            "--out",
            type=click.Path(path_type=Path),
            required=True,
            help="experiment directory (an existing one is resumed)",
        ),
    ]
    # The params of a throwaway command: click's decorators, in click's order.
    return click.command()(options.stack(*decorators)(lambda: None)).params


class ExperimentCommand(click.Command):
    """One experiment's subcommand: an option that is another experiment's is named as such."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        try:
            return super().parse_args(ctx, args)
        except click.NoSuchOption as error:
            owners = [
                name for name in _names() if name != self.name and error.option_name in _flags(name)
            ]
            if not owners:
                raise
            raise CliError(
                f"{error.option_name}: an option of {', '.join(owners)}, not of {self.name}"
            ) from None


def _flags(name: str) -> set[str]:
    """Every option flag the experiment `name` takes."""
    command = _command(name)
    return {flag for param in command.params for flag in param.opts}


def _names() -> list[str]:
    return sorted(plugins.names(plugins.EXPERIMENTS))


def _spec(name: str) -> "ExperimentSpec":
    # start-up: keeps the experiments' declarations (pydantic, numpy) off analytic --help
    from gainfarm.analytic.experiments.registry import load

    try:
        return load(name)
    except plugins.PluginError as error:
        raise CliError(f"NAME: {error}") from None


def _command(name: str) -> click.Command:
    """The subcommand of experiment `name`, made from its declaration."""
    spec = _spec(name)
    own = [
        click.Option(
            [option.flag, option.parameter],
            default=option.default,
            show_default=option.default is not None,
            metavar=option.metavar,
            help=option.help,
        )
        for option in spec.options
    ]
    return ExperimentCommand(
        spec.name,
        params=[*_shared_options(spec.duration), *own],
        callback=lambda **values: _run(spec, **values),
        help=spec.help or spec.summary[:1].upper() + spec.summary[1:] + ".",
        short_help=spec.summary,
    )


class Experiments(click.Group):
    """The installed experiments, one subcommand each, built when named."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return _names()

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        return _command(cmd_name)


@click.group(cls=Experiments, no_args_is_help=True)
def experiment() -> None:
    """Run one of the installed experiments: the paper's (popsize, generic-vs-specific, speed),
    the optimiser comparison (algorithms), or the test of the claim that tuned controllers'
    data teach the dynamics better (dataset-value), the learned feed-forward against PD +
    gravity compensation and the true model (feedforward), or what the plant's assumptions do
    to the findings (sensitivity). `analytic experiment NAME --help` lists NAME's options; an
    experiment directory (--out) that exists is resumed."""


def _run(
    spec: "ExperimentSpec",
    reps: int,
    pop: int,
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
    from pydantic import ValidationError
    from rich.console import Console

    from gainfarm.analytic.evaluators.farm import FarmClient
    from gainfarm.analytic.experiments.runner import Experiment
    from gainfarm.analytic.tuning.config import RunConfig
    from gainfarm.analytic.tuning.run import RunBusy
    from gainfarm.analytic.view.progress import Display
    from gainfarm.schemas.trajectory import TrajectorySpec

    options.check_load(payload, payload_com)
    identity = check_farm(connect, local, tls, participant)
    limits = options.limits_from(limits_file)
    values: dict[str, object] = {}
    for option in spec.options:
        text = given[option.parameter]
        if text is None:  # not given and no default: the experiment's own
            continue
        try:
            values[option.parameter] = option.parse(text)
        except ValueError as error:
            raise CliError(f"{option.flag}: {error}") from None
    try:
        base = RunConfig(
            pop=pop,
            trajectories=(
                TrajectorySpec() if duration is None else TrajectorySpec(duration=duration),
            ),
            model=options.with_load(options.model_spec(plant), payload, payload_com, plant),
            limits=limits,
            generations=generations,
            evaluations=evaluations,
            keep="front",
        )
        base = spec.prepare(base, values)
        trajectories = list(spec.trajectories(base, values))
    except ValidationError as error:
        raise CliError(config_problem(error)) from None
    except ValueError as error:
        raise CliError(str(error)) from None
    followable(trajectories, spec.trajectory_option)
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
            own_farm(connect, workers) as (endpoints, own_workers),
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
                spec.run(experiment, base, reps, **values)
            except (ValueError, RunBusy) as error:
                raise CliError(str(error)) from None
    except OSError as error:
        if isinstance(error, ConnectionError):
            raise CliError(farm_problem(connect, error)) from None
        raise unwritable(error, "run the same command again to go on") from None
    except KeyboardInterrupt:
        interrupts.stop("analytic", "stopped; run the same command again to go on")
    click.echo(f"{spec.name}: report, figures and results.csv in {out}/", err=True)
