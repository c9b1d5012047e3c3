"""`analytic dashboard` once it runs: what its function in analytic/commands/dashboard.py does."""

from pathlib import Path

import click

from gainfarm.analytic.view.dashboard import NoBokeh, Watch
from gainfarm.analytic.view.dashboard import run_forever as run_dashboard
from gainfarm.analytic.view.dashboard import serve as serve_dashboard
from gainfarm.cli import values
from gainfarm.cli.app import CliError
from gainfarm.edges.transport import open_session


def dashboard(
    runs: tuple[Path, ...],
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    port: int,
    robot: str | None,
) -> None:
    """`analytic dashboard` with its options as parsed (analytic/commands/dashboard.py)."""
    for root in runs:
        if not root.is_dir():
            why = "not a directory" if root.exists() else "no such directory"
            raise CliError(f"RUNS: {str(root)!r}: {why}")
    if tls is not None and not connect:
        raise CliError("--tls needs --connect: the farm to watch")
    identity = values.identity(tls, "analytic", participant)
    session = None
    if connect:
        try:
            session = open_session("client", connect=connect, identity=identity)
        except (ValueError, ConnectionError) as error:
            raise CliError(f"--connect: {error}") from None
    try:
        with Watch(runs or (Path("runs"),), session, ", ".join(connect), robot=robot) as watch:
            try:
                server = serve_dashboard(watch, port)
            except OSError as error:
                raise CliError(f"--port: cannot serve on {port}: {error.strerror}") from None
            except NoBokeh as error:
                raise CliError(str(error)) from None
            try:
                click.echo(f"dashboard at http://127.0.0.1:{port}/ (Ctrl-C stops it)")
                run_dashboard()
            finally:
                server.stop()
    finally:
        if session is not None:
            session.close()
