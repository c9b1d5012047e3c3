"""`analytic dashboard`: runs and their farm, live in a web page."""

from pathlib import Path

import click

from gainfarm.cli import options
from gainfarm.cli.app import CliError


def _port() -> int:
    from gainfarm.analytic.view.dashboard import DASHBOARD_PORT

    return DASHBOARD_PORT


@click.command()
@click.argument("runs", nargs=-1, type=click.Path(path_type=Path))
@click.option(
    "--connect",
    multiple=True,
    help="the farm's broker, to show its workers, queue and throughput  [default: not shown]",
)
@options.tls("with --connect: the credentials of a secure farm")
@options.participant("analytic")
@click.option(
    "--port",
    type=click.IntRange(min=1, max=65535),
    default=options.Later(_port),
    show_default=True,
    help="the page's port, on 127.0.0.1",
)
def dashboard(
    runs: tuple[Path, ...],
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    port: int,
) -> None:
    """Watch tuning runs and their farm live, in a web page on this machine: each run's front
    and hypervolume curve, the farm's workers, queue and throughput. RUNS are run directories,
    or directories holding runs (an experiment's, runs/), whose new runs join the page as they
    start  [default: runs]. Until Ctrl-C."""
    from gainfarm.analytic.view.dashboard import NoBokeh, Watch
    from gainfarm.analytic.view.dashboard import run_forever as run_dashboard
    from gainfarm.analytic.view.dashboard import serve as serve_dashboard
    from gainfarm.edges.transport import open_session

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
        with Watch(runs or (Path("runs"),), session, ", ".join(connect)) as watch:
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
