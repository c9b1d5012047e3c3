"""`analytic evaluate` once it runs: what its function in analytic/commands/evaluate.py does."""

from pathlib import Path

from gainfarm import plugins
from gainfarm.cli.app import CliError
from gainfarm.cli.scores import show_scores
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, read_episode
from gainfarm.schemas.objectives import score


def evaluate(log: Path, as_json: bool, robot: str | None = None) -> None:
    """`analytic evaluate` with its options as parsed (analytic/commands/evaluate.py); `robot`
    None: not given."""
    if log.is_dir():
        raise CliError(f"LOG: {str(log)!r} is a directory, not an episode log (an MCAP file)")
    if not log.is_file():
        raise CliError(f"LOG: {str(log)!r}: no such file")
    try:
        episode = read_episode(log)
        ran_on = episode.metadata.spec.plant.robot
        if robot is not None and ran_on != robot:
            raise CliError(f"--robot: {robot}, but {str(log)!r} is an episode of {ran_on}")
        # The objectives its job named: a plug-in's is computed by the plug-in, if installed.
        scores = score(
            episode, plugins.load_plugins(plugins.OBJECTIVES, episode.metadata.spec.objectives)
        )
    except (NotAnEpisodeLog, plugins.PluginError) as error:
        raise CliError(str(error)) from None
    show_scores(scores, log, as_json)
