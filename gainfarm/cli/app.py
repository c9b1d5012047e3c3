"""Bad input gets one clear error line and a non-zero exit: the shared rules of every CLI."""

import logging
import sys
from collections.abc import Callable

import click

from gainfarm.cli import interrupts

USAGE_ERROR = 2
# -h as well as --help, on every command and subcommand (click inherits context settings).
CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"]}


class CliError(click.ClickException):
    """A problem with what the user asked for, said in one line."""

    exit_code = USAGE_ERROR


def parse_numbers(option: str, text: str, count: int | None = None) -> tuple[float, ...]:
    """Comma-separated numbers from an option's value (exactly `count` of them, if given)."""
    expected = f"{count} " if count is not None else ""
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise CliError(
            f"{option}: expected {expected}comma-separated numbers, got {text!r}"
        ) from None
    if count is not None and len(values) != count:
        raise CliError(f"{option}: expected {count} numbers, got {len(values)}")
    return values


def program_group(help: str | None) -> Callable[[Callable[..., None]], click.Group]:
    """The group of a command line's commands: its help with no arguments, -h and --help,
    and --version (the installed gainfarm's)."""

    def decorate(function: Callable[..., None]) -> click.Group:
        function = click.version_option(package_name="gainfarm", message="%(prog)s %(version)s")(
            function
        )
        return click.group(help=help, no_args_is_help=True, context_settings=CONTEXT_SETTINGS)(
            function
        )

    return decorate


def run_app(command: click.Command, program: str) -> None:
    """Run a click command, turning every user error into `program: error: ...` on one line,
    and a Ctrl-C at any moment into `program: interrupted` and exit status 130."""
    interrupts.install()
    try:
        # Not command.main(): it turns a KeyboardInterrupt into an empty line and Abort.
        with command.make_context(program, sys.argv[1:]) as context:
            command.invoke(context)
    except click.exceptions.Exit as done:  # --help, --version
        sys.exit(done.exit_code)
    except click.exceptions.NoArgsIsHelpError as help_request:
        click.echo(help_request.ctx.get_help() if help_request.ctx else "", err=True)
        sys.exit(USAGE_ERROR)
    except click.ClickException as error:
        if interrupts.INTERRUPTED.is_set() and interrupts.ours():
            interrupts.stop(program)  # the error is the interruption's, not the user's
        click.echo(f"{program}: error: {error.format_message()}", err=True)
        sys.exit(error.exit_code)
    except (click.Abort, KeyboardInterrupt):
        interrupts.stop(program)
    except Exception:
        # What a Ctrl-C broke on its way (an import it cut short, a library's cleanup) is the
        # interruption's doing, not a failure of its own.
        if interrupts.INTERRUPTED.is_set() and interrupts.ours():
            interrupts.stop(program)
        raise
    # A Ctrl-C the command did not see (dropped in a finaliser, or pressed as it finished):
    # the user asked it to stop, so it did not simply succeed.
    if interrupts.INTERRUPTED.is_set() and interrupts.ours():
        interrupts.stop(program)


def setup_logging(program: str, level: str) -> None:
    """Services log one line per event to stderr, each prefixed by the program that wrote it."""
    logging.basicConfig(
        level=level.upper(),
        format=f"%(asctime)s {program} %(levelname)s %(message)s",
        datefmt="%H:%M:%S",
    )
