"""`analytic excite`: safe excitation references to record on a real arm, for `calibrate`."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import uncertainty
from gainfarm.cli.options import robot

# Light: the defaults and bounds click checks before anything heavy loads.
DURATION = 10.0  # s: every joint moves 0.19 rad at least (seeds 0-99; 0.20 at 3 s)
COUNT = 10
MAX_COUNT = 100  # two digits in the files' names


@click.command()
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    required=True,
    metavar="DIR",
    help="directory to write (new, or empty): the references, controller.json, README.md",
)
@click.option(
    "--duration",
    type=float,
    default=DURATION,
    metavar="S",
    show_default=True,
    help="seconds per excitation (0.1 to 120)",
)
@click.option(
    "--count",
    type=click.IntRange(1, MAX_COUNT),
    default=COUNT,
    metavar="N",
    show_default=True,
    help="excitations to write",
)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    metavar="K",
    show_default=True,
    help="excitation NN is the fourier trajectory of seed K + NN",
)
@uncertainty(
    "the plant ranges the gains must be stable on, a TOML file in the form of the shipped "
    "models/uncertainty.toml  [default: the robot's shipped ranges]"
)
@robot("the arm to record")
def excite(**given: Any) -> None:
    """Write safe excitation references to record on a real arm, for `analytic calibrate`.

    Each is a fourier trajectory (every joint moves, rest to rest) at 500 Hz as JSON and as a
    ROS 2 JointTrajectory in MCAP, with the PD gains to play it with and a README saying what to
    record. Refused, with nothing written, unless every reference stays within the arm's
    published limits and moves every joint, and the gains are stable on the nominal plant and on
    plants drawn from the uncertainty ranges.
    """
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.excite import excite as work

    work(**given)
