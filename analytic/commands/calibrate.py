"""`analytic calibrate`: fit a twin of an arm to its logged episodes, as a plant file."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import bag_topics
from gainfarm.cli import options


@click.command()
@click.argument("logs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default="twin.toml",
    show_default=True,
    help="where to write the twin (a plant file: `--plant TWIN` runs on it)",
)
@options.plant()
@options.robot("the arm the logs are of (a --plant FILE's own arm if not given)")
@options.load()
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="the bootstrap's resamples of the episodes",
)
@bag_topics
@click.option("--json", "as_json", is_flag=True, help="print the fit as one JSON object")
def calibrate(**given: Any) -> None:
    """Fit a twin of an arm to LOGS, its recorded episodes (`analytic excite` says what to
    record): gainfarm episode logs, or ROS 2 bags (directories, MCAP or SQLite files) of
    sensor_msgs/JointState at 500 Hz. It fits the delay, rotor inertias, friction, joint
    stiffness and damping, and the links' masses with a payload, each with its uncertainty; the
    twin is --plant's plant (the robot's own model, the controller's settings, and every number
    the logs cannot tell) with them; --payload: the load the arm was told as it recorded them.
    The twin is of --robot's arm, and stands for no other."""
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.calibrate import calibrate as work

    # Not given, --robot defers to a twin's own arm (--plant FILE); given, a twin of another
    # arm is refused.
    source = click.get_current_context().get_parameter_source("robot")
    if source is not click.core.ParameterSource.COMMANDLINE:
        given["robot"] = None
    work(**given)
