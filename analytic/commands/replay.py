"""`analytic replay`: an episode log as a video."""

from pathlib import Path

import click

from gainfarm.cli.app import CliError
from gainfarm.cli.options import Later


def _default(name: str) -> int:
    from gainfarm.analytic.view import replay

    return getattr(replay, name)


@click.command()
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="the MP4 to write")
@click.option(
    "--fps",
    type=click.IntRange(min=1, max=120),
    default=Later(lambda: _default("DEFAULT_FPS")),
    show_default=True,
    help="frames per second of simulated time",
)
@click.option(
    "--width",
    type=click.IntRange(min=16, max=3840),
    default=Later(lambda: _default("DEFAULT_WIDTH")),
    show_default=True,
    help="pixels, even",
)
@click.option(
    "--height",
    type=click.IntRange(min=16, max=2160),
    default=Later(lambda: _default("DEFAULT_HEIGHT")),
    show_default=True,
    help="pixels, even",
)
def replay(log: Path, out: Path, fps: int, width: int, height: int) -> None:
    """Render an episode log as a video: the arm (MuJoCo, offscreen), the reference path (green)
    and the path the flange took (magenta)."""
    from gainfarm.analytic.view.replay import ReplayError
    from gainfarm.analytic.view.replay import replay as replay_episode

    # As `analytic evaluate` says it: a directory is not a missing file.
    if log.is_dir():
        raise CliError(f"LOG: {str(log)!r} is a directory, not an episode log (an MCAP file)")
    if not log.is_file():
        raise CliError(f"LOG: {str(log)!r}: no such file")
    try:
        frames = replay_episode(log, out, fps, width, height)
    except ReplayError as error:
        raise CliError(str(error)) from None
    click.echo(f"{out}: {frames} frames, {width}x{height} at {fps} fps")
