"""`analytic validate`: an arm's logged episodes replayed on a twin and on the nominal plant."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import bag_topics, farm_options, prechecked, robot_read
from gainfarm.cli import options

REPORT = "validation.json"


@click.command()
@click.argument("twin", type=click.Path(path_type=Path))
@click.argument("logs", nargs=-1, required=True, type=click.Path(path_type=Path))
@farm_options
@options.plant("--nominal", help="the plant to compare the twin with: a named one or a file")
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    help=f"where the replays' episodes and {REPORT} go  [default: runs/validate-TIME]",
)
@click.option(
    "--played",
    multiple=True,
    type=click.Path(path_type=Path),
    metavar="FILE",
    help="what a robot's bags played (repeat for several): an excitation of `analytic excite` "
    "or a controller of `analytic export`; each bag is paired with the reference it follows",
)
@bag_topics
@click.option("--json", "as_json", is_flag=True, help="print the report as one JSON object")
@robot_read("the twin")
def validate(**given: Any) -> None:
    """Replay LOGS, an arm's episodes (held out of the calibration), through TWIN and the
    --nominal plant on the farm: per joint, the simulation error of q and of the joint torque
    on each, and each episode's f_acc and f_t as the twin predicts them against the log's.
    LOGS are gainfarm episode logs, or a robot's ROS 2 bags of what --played names."""
    prechecked(given)  # before the work's imports: the contract, MuJoCo, Zenoh, pymoo
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.validate import validate as work

    work(**given)
