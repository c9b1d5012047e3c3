"""`broker`: the Zenoh router and job scheduler of the farm (it grows with the farm issue)."""

from importlib.metadata import version as package_version

import click

from schemas.errors import run_app


@click.group(help=__doc__, no_args_is_help=True)
def app() -> None:
    pass


@app.command()
def version() -> None:
    """Print the gainfarm version."""
    click.echo(package_version("gainfarm"))


def main() -> None:
    run_app(app, "broker")
