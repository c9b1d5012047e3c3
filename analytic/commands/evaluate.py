"""`analytic evaluate`: an episode's scores, from its MCAP log alone."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import unless_default
from gainfarm.cli import options


@click.command()
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="print the scores as one JSON object")
@options.robot("the arm the episode is of (the log names it; refused if it names another)")
def evaluate(**given: Any) -> None:
    """Score an episode from its MCAP log alone: f_acc, f_t and diagnostics."""
    given = unless_default(given, "robot")  # not given: the one the log names
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.evaluate import evaluate as work

    work(**given)
