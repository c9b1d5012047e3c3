"""`analytic evaluate`: an episode's scores, from its MCAP log alone."""

from pathlib import Path

import click

from gainfarm.cli.app import CliError


@click.command()
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="print the scores as one JSON object")
def evaluate(log: Path, as_json: bool) -> None:
    """Score an episode from its MCAP log alone: f_acc, f_t and diagnostics."""
    from gainfarm import plugins
    from gainfarm.cli.scores import show_scores
    from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, read_episode
    from gainfarm.schemas.objectives import score

    if log.is_dir():
        raise CliError(f"LOG: {str(log)!r} is a directory, not an episode log (an MCAP file)")
    if not log.is_file():
        raise CliError(f"LOG: {str(log)!r}: no such file")
    try:
        episode = read_episode(log)
        # The objectives its job named: a plug-in's is computed by the plug-in, if installed.
        scores = score(
            episode, plugins.load_plugins(plugins.OBJECTIVES, episode.metadata.spec.objectives)
        )
    except (NotAnEpisodeLog, plugins.PluginError) as error:
        raise CliError(str(error)) from None
    show_scores(scores, log, as_json)
