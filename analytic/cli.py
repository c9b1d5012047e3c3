"""`analytic`: the analytic layer's command line. For now: score an episode log."""

import json
from pathlib import Path

import click

from analytic.objectives import score
from analytic.report import print_scores
from schemas.errors import CliError, run_app
from schemas.mcap_episode import NotAnEpisodeLog, read_episode


@click.group(help=__doc__, no_args_is_help=True)
def app() -> None:
    pass


@app.command()
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="print the scores as one JSON object")
def evaluate(log: Path, as_json: bool) -> None:
    """Score an episode from its MCAP log alone: f_acc, f_t and diagnostics."""
    if not log.is_file():
        raise CliError(f"{str(log)!r}: no such file")
    try:
        scores = score(read_episode(log))
    except NotAnEpisodeLog as error:
        raise CliError(str(error)) from None
    if as_json:
        click.echo(json.dumps({**scores.model_dump(), "log": str(log)}))
    else:
        print_scores(scores, source=str(log))


def main() -> None:
    run_app(app, "analytic")
