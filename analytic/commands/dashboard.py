"""`analytic dashboard`: runs and their farm, live in a web page."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import robot_read
from gainfarm.cli import options
from gainfarm.cli.app import CliError

# Held here, not imported, so that parsing and --help load nothing heavy: tests/analytic/commands/
# test_held_defaults.py keeps each equal to its source's.
PORT = 5006  # analytic.view.dashboard.DASHBOARD_PORT


@click.command()
@click.argument("runs", nargs=-1, type=click.Path(path_type=Path))
@click.option(
    "--connect",
    multiple=True,
    help="the farm's broker, to show its workers, queue and throughput  [default: not shown]",
)
@options.tls("with --connect: the credentials of a secure farm")
@options.participant("analytic")
@click.option(
    "--port",
    type=click.IntRange(min=1, max=65535),
    default=PORT,
    show_default=True,
    help="the page's port, on 127.0.0.1",
)
@robot_read("the runs", help="the arm whose runs to show", default="every arm's")
def dashboard(**given: Any) -> None:
    """Watch tuning runs and their farm live, in a web page on this machine: each run's front
    and hypervolume curve, the farm's workers, queue and throughput. RUNS are run directories,
    or directories holding runs (an experiment's, runs/), whose new runs join the page as they
    start  [default: runs]; with --robot, only the runs of that arm (a FILE: your own arm, whose
    runs the page can then read). Until Ctrl-C."""
    if given["tls"] is not None and not given["connect"]:  # before the work's imports (Bokeh)
        raise CliError("--tls needs --connect: the farm to watch")
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.dashboard import dashboard as work

    work(**given)
