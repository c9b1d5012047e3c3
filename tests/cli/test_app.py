"""What every command line shares (cli/app.py): -h, --version, and every command in the help."""

import os
import subprocess
import sys
from importlib.metadata import version

import pytest

from gainfarm.analytic.cli import app as analytic_app
from gainfarm.broker.cli import app as broker_app
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
def test_every_command_takes_minus_h(program: str) -> None:
    for command in PROGRAMS[program].commands:
        shown = run(program, command, "-h")
        assert shown.returncode == 0, shown.stderr
        assert shown.stdout.startswith(f"Usage: {program} {command} ")
