"""`analytic replay` once it runs: what its function in analytic/commands/replay.py does."""

from pathlib import Path

import click

from gainfarm.analytic.view.replay import ReplayError
from gainfarm.analytic.view.replay import replay as replay_episode
from gainfarm.cli.app import CliError


def replay(log: Path, out: Path, fps: int, width: int, height: int, robot: str | None) -> None:
    """`analytic replay` with its options as parsed (analytic/commands/replay.py)."""
    # As `analytic evaluate` says it: a directory is not a missing file.
    if log.is_dir():
        raise CliError(f"LOG: {str(log)!r} is a directory, not an episode log (an MCAP file)")
    if not log.is_file():
        raise CliError(f"LOG: {str(log)!r}: no such file")
    try:
        frames = replay_episode(log, out, fps, width, height, robot)
    except ReplayError as error:
        raise CliError(str(error)) from None
    click.echo(f"{out}: {frames} frames, {width}x{height} at {fps} fps")
