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
from gainfarm.analytic.commands.shared import farm_options, pop_option, termination_options
from gainfarm.cli import options
from gainfarm.cli.app import CliError

if TYPE_CHECKING:
    from gainfarm.analytic.experiments.registry import ExperimentSpec


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
        options.robot("the arm the experiment's runs tune"),
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


def _run(spec: "ExperimentSpec", **given: object) -> None:
    # start-up: the work loads when the experiment runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.experiment import run

    run(spec, **given)  # type: ignore[arg-type]
