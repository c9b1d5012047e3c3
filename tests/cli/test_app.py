"""What every command line shares (gainfarm/cli/app.py): -h, --version, every command in the
help, and a group that imports only the command run."""

import os
import subprocess
import sys
from importlib.metadata import version

import click
import pytest

from gainfarm.analytic.cli import app as analytic_app
from gainfarm.broker.cli import app as broker_app
from gainfarm.cli.app import LazyCommands
from gainfarm.worker.cli import app as worker_app

PROGRAMS = {"analytic": analytic_app, "broker": broker_app, "worker": worker_app}


def run(program: str, *arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", program, *arguments],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "80"},
    )


@pytest.mark.parametrize("program", PROGRAMS)
def test_version_and_short_help(program: str) -> None:
    shown = run(program, "--version")
    assert shown.returncode == 0, shown.stderr
    assert shown.stdout == f"{program} {version('gainfarm')}\n"
    short, long = run(program, "-h"), run(program, "--help")
    assert short.returncode == 0 and short.stdout == long.stdout
    assert short.stdout.startswith(f"Usage: {program} [OPTIONS] COMMAND")


@pytest.mark.parametrize("program", PROGRAMS)
def test_the_help_lists_every_command_uncut(program: str) -> None:
    """Each command's line in the list, its summary whole (click cuts a long one with '...')."""
    listed = run(program, "--help").stdout.split("Commands:\n", 1)[1].splitlines()
    names = [line.split()[0] for line in listed if line.strip()]
    assert names == sorted(PROGRAMS[program].commands)
    assert not any(line.endswith("...") for line in listed), listed


@pytest.mark.parametrize("program", PROGRAMS)
@pytest.mark.slow
def test_every_command_takes_minus_h(program: str) -> None:
    for command in PROGRAMS[program].commands:
        shown = run(program, command, "-h")
        assert shown.returncode == 0, shown.stderr
        assert shown.stdout.startswith(f"Usage: {program} {command} ")


def test_the_lazy_group_lists_each_command_by_the_summary_it_runs_with() -> None:
    """`analytic --help` lists the summaries of analytic/cli.py's table without importing a
    command; each name there is its module's command, whose short help that summary is."""
    commands = analytic_app.commands
    assert isinstance(commands, LazyCommands)
    for name in sorted(commands):
        summary = commands.summary(name)
        command = commands[name]  # imports its module now
        assert isinstance(command, click.Command) and command.name == name
        assert command.get_short_help_str(limit=1000) == summary
    context = click.Context(analytic_app)
    assert "nonsense" not in commands and analytic_app.get_command(context, "nonsense") is None


def test_an_unknown_command_is_one_line() -> None:
    shown = run("analytic", "nonsense")
    assert shown.returncode == 2
    assert shown.stderr == "analytic: error: No such command 'nonsense'.\n"
