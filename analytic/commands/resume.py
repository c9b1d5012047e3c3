"""`analytic resume`: a stopped run, on from its last checkpoint."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import farm_options, prechecked, unless_default
from gainfarm.cli import options


@click.command()
@click.argument("run_dir", type=click.Path(path_type=Path))
@options.robot("the run's arm, if a description file describes it (the run names its arm)")
@farm_options
def resume(**given: Any) -> None:
    """Continue a stopped run from its last checkpoint; or finish one whose evolution had
    ended (its front's validation, the held-out check, the figures and report.md)."""
    given = unless_default(given, "robot")  # not given: the one the run names
    prechecked(given, "run_dir")  # before the work's imports: the contract, MuJoCo, Zenoh, pymoo
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.resume import resume as work

    work(**given)
