"""Bad input gets one clear error line and a non-zero exit: the shared rules of every CLI."""

import importlib
import logging
import sys
from collections.abc import Callable, Iterator, Mapping, MutableMapping

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


class LazyCommands(MutableMapping[str, click.Command]):
    """A group's commands by name, each imported only when it is looked up (to run it, or show
    its own help): `lazy` maps a name to ("module:attribute", summary). The summary is the one
    the group's --help lists, so that listing imports nothing; it is the command's short help."""

    def __init__(self, lazy: Mapping[str, tuple[str, str]]):
        self.lazy = dict(lazy)
        self.loaded: dict[str, click.Command] = {}

    def summary(self, name: str) -> str:
        if name in self.lazy:
            return self.lazy[name][1]
        return self.loaded[name].get_short_help_str(limit=1000)

    def __getitem__(self, name: str) -> click.Command:
        if name not in self.loaded:
            module, _, attribute = self.lazy[name][0].partition(":")
            command = getattr(importlib.import_module(module), attribute)
            if not isinstance(command, click.Command):
                raise TypeError(f"{self.lazy[name][0]} is not a click command")
            command.short_help = command.short_help or self.lazy[name][1]
            self.loaded[name] = command
        return self.loaded[name]

    def __setitem__(self, name: str, command: click.Command) -> None:
        self.loaded[name] = command
        self.lazy.pop(name, None)

    def __delitem__(self, name: str) -> None:
        if self.lazy.pop(name, None) is None:
            del self.loaded[name]

    def __iter__(self) -> Iterator[str]:
        return iter(sorted(self.lazy.keys() | self.loaded.keys()))

    def __len__(self) -> int:
        return len(self.lazy.keys() | self.loaded.keys())

    def __contains__(self, name: object) -> bool:
        return name in self.lazy or name in self.loaded


class LazyGroup(click.Group):
    """A group whose --help lists its commands, and whose command line is parsed, with only the
    command run imported (`LazyCommands`)."""

    commands: LazyCommands  # type: ignore[assignment]

    def __init__(self, *args: object, lazy: Mapping[str, tuple[str, str]], **kwargs: object):
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.commands = LazyCommands(lazy)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, self.commands.summary(name)) for name in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def program_group(
    help: str | None, commands: Mapping[str, tuple[str, str]] | None = None
) -> Callable[[Callable[..., None]], click.Group]:
    """The group of a command line's commands: its help with no arguments, -h and --help,
    and --version (the installed gainfarm's). `commands`, if given: the commands the group loads
    only when one runs (LazyGroup: name -> ("module:attribute", summary))."""

    def decorate(function: Callable[..., None]) -> click.Group:
        function = click.version_option(package_name="gainfarm", message="%(prog)s %(version)s")(
            function
        )
        lazy = {"cls": LazyGroup, "lazy": commands} if commands is not None else {}
        return click.group(
            help=help, no_args_is_help=True, context_settings=CONTEXT_SETTINGS, **lazy
        )(function)

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
