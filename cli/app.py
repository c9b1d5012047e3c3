"""Bad input gets one clear error line and a non-zero exit: the shared rules of every CLI."""

import logging
import sys

import click

USAGE_ERROR = 2


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


def run_app(command: click.Command, program: str) -> None:
    """Run a click command, turning every user error into `program: error: ...` on one line."""
    try:
        command.main(prog_name=program, standalone_mode=False)
    except click.exceptions.NoArgsIsHelpError as help_request:
        click.echo(help_request.ctx.get_help() if help_request.ctx else "", err=True)
        sys.exit(USAGE_ERROR)
    except click.ClickException as error:
        click.echo(f"{program}: error: {error.format_message()}", err=True)
        sys.exit(error.exit_code)
    except (click.Abort, KeyboardInterrupt):
        click.echo(f"{program}: interrupted", err=True)
        sys.exit(130)


def setup_logging(program: str, level: str) -> None:
    """Services log one line per event to stderr, each prefixed by the program that wrote it."""
    logging.basicConfig(
        level=level.upper(),
        format=f"%(asctime)s {program} %(levelname)s %(message)s",
        datefmt="%H:%M:%S",
    )
