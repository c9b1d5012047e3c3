"""`analytic evaluate`: an episode's scores, from its MCAP log alone."""

from pathlib import Path
from typing import Any

import click


@click.command()
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="print the scores as one JSON object")
def evaluate(**given: Any) -> None:
    """Score an episode from its MCAP log alone: f_acc, f_t and diagnostics."""
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.evaluate import evaluate as work

    work(**given)
