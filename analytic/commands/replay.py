"""`analytic replay`: an episode log as a video."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import robot_read

# Held here, not imported, so that parsing and --help load nothing heavy: tests/analytic/commands/
# test_held_defaults.py keeps each equal to its source's.
# analytic.view.replay's DEFAULT_FPS, DEFAULT_WIDTH and DEFAULT_HEIGHT
FPS, WIDTH, HEIGHT = 30, 640, 480


@click.command()
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="the MP4 to write")
@click.option(
    "--fps",
    type=click.IntRange(min=1, max=120),
    default=FPS,
    show_default=True,
    help="frames per second of simulated time",
)
@click.option(
    "--width",
    type=click.IntRange(min=16, max=3840),
    default=WIDTH,
    show_default=True,
    help="pixels, even",
)
@click.option(
    "--height",
    type=click.IntRange(min=16, max=2160),
    default=HEIGHT,
    show_default=True,
    help="pixels, even",
)
@robot_read("the log")
def replay(**given: Any) -> None:
    """Render an episode log as a video: the arm it ran (MuJoCo, offscreen), the reference path
    (green) and the path the flange took (magenta)."""
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.replay import replay as work

    work(**given)
