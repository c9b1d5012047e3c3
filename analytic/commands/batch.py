"""`analytic batch`: fixed candidates' episodes on the farm, every one kept and scored."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import farm_options, prechecked, unless_default
from gainfarm.cli import options

# Held here, not imported, so that parsing and --help load nothing heavy: tests/analytic/commands/
# test_held_defaults.py keeps each equal to its source's.
DEADLINE = 600.0  # s: analytic.evaluators.farm.DEFAULT_DEADLINE


@click.command()
@farm_options
@click.option(
    "--gains",
    "gains_file",
    type=click.Path(path_type=Path),
    help="the candidates: a controller from `analytic export` (JSON or YAML), a list of "
    '{"kp": [...], "kd": [...]} objects (one gain per joint of the arm), or a run\'s front.csv '
    "(every member)  [default: the arm's default gains]",
)
@options.trajectory(multiple=True, help="repeat for several")
@options.duration()
@options.placement()
@options.robot("the arm the candidates run on")
@options.joints(help=None)
@options.plant()
@options.load()
@options.feedforward()
@click.option(
    "--run-dir",
    type=click.Path(path_type=Path),
    help="where episodes/ and evaluations.json go  [default: runs/batch-TIME]",
)
@click.option(
    "--deadline",
    type=click.FloatRange(min=1),
    default=DEADLINE,
    show_default=True,
    help="seconds before an unanswered job is resubmitted",
)
@click.option("--json", "as_json", is_flag=True, help="print one JSON object per evaluation")
def batch(**given: Any) -> None:
    """Evaluate candidate gains on trajectories through the farm; keep and score every episode."""
    # Not given: the robot's workspace centre, and each kind's default duration on it.
    given = unless_default(given, "center", "duration")
    prechecked(given)  # before the work's imports: the contract, MuJoCo, Zenoh, pymoo
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.batch import batch as work

    work(**given)
