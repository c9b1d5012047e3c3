"""`analytic export`: a run's controller, out of the run."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import prechecked, robot_read

# Held here, not imported, so that parsing and --help load nothing heavy: tests/analytic/commands/
# test_held_defaults.py keeps each equal to its source's.
FORMATS = ("json", "yaml", "ros2_control")  # analytic.view.export.FORMATS


@click.command()
@click.argument("run_dir", metavar="RUN", type=click.Path(path_type=Path))
@click.option(
    "--member",
    default="recommended",
    show_default=True,
    metavar="recommended|knee|accurate|smooth|N",
    help="which front member: the recommended one (the best compromise among those that "
    "dominate the default gains; refused if none does), the knee (the best compromise of the "
    "whole front), the most accurate, the smoothest, or row N of front.csv (the report's #)",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(FORMATS),
    default="json",
    show_default=True,
    help="json: what `analytic batch --gains` and `worker episode --gains` read; yaml: the "
    "same document; ros2_control: a controller_manager parameter file running the gains as a "
    "PD on the effort interface",
)
@click.option(
    "--out", type=click.Path(path_type=Path), help="file to write  [default: standard output]"
)
@robot_read("the run")
def export(**given: Any) -> None:
    """Write a run's controller: one front member's gains, with its arm's joints, units, what it
    assumes of the arm, its scores and the run it came from."""
    prechecked(given, "run_dir")  # before the work's imports: the contract, MuJoCo, pymoo
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.export import export as work

    work(**given)
