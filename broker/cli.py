"""`broker`: the farm's Zenoh router and job scheduler (`start`), a look at it (`status`), and
development credentials for a secure farm (`certs`)."""

import logging
import signal
import threading
from importlib.metadata import version as package_version
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from broker.certs import DEFAULT_HOSTS, write_dev_credentials
from broker.service import DEFAULT_LISTEN, Broker
from broker.status import BrokerUnavailable, query_status
from cli import options
from cli.app import CliError, run_app, setup_logging
from schemas.security import Role
from schemas.transport import open_session
from schemas.wire import BadMessage, BrokerStatus

log = logging.getLogger("gainfarm.broker")


@click.group(help=__doc__, no_args_is_help=True)
def app() -> None:
    pass


@app.command()
@click.option(
    "--listen",
    multiple=True,
    default=[DEFAULT_LISTEN],
    show_default=True,
    help="Zenoh endpoint to listen on (repeat for several)",
)
@click.option(
    "--lease-seconds",
    type=click.FloatRange(min=0.1),
    default=60.0,
    show_default=True,
    help="a job not returned this long after its lease goes back to the queue",
)
@options.tls(
    "secure profile: TLS with client certificates and per-role access control; "
    "directory with ca.pem, broker.pem and broker.key (see `broker certs`)"
)
@options.log_level()
def start(listen: tuple[str, ...], lease_seconds: float, tls: Path | None, log_level: str) -> None:
    """Route the farm and schedule its jobs until SIGTERM or Ctrl-C."""
    setup_logging("broker", log_level)
    identity = options.identity(tls, "broker")
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    try:
        broker = Broker(listen, lease_seconds=lease_seconds, identity=identity)
    except (ValueError, ConnectionError) as error:
        raise CliError(f"--listen: {error}") from None
    with broker:
        while not stop.wait(1.0):
            pass
    log.info("broker stopped after %d jobs", broker.queue.jobs_done)


@app.command()
@options.connect("the broker's Zenoh endpoint")
@options.tls(
    "a secure farm: directory with ca.pem and the broker's (or another role's) pem and key"
)
@click.option(
    "--as",
    "role",
    type=click.Choice(["broker", "analytic", "worker"]),
    default="broker",
    show_default=True,
    help="with --tls: whose credentials to use",
)
@click.option("--json", "as_json", is_flag=True, help="print the status as one JSON object")
def status(connect: tuple[str, ...], tls: Path | None, role: Role, as_json: bool) -> None:
    """Show the farm: workers, queue depth per study, throughput."""
    identity = options.identity(tls, role)
    try:
        session = open_session("client", connect=connect, identity=identity)
    except (ValueError, ConnectionError) as error:
        raise CliError(f"--connect: {error}") from None
    try:
        farm = query_status(session, timeout=5.0)
    except (BrokerUnavailable, BadMessage) as error:
        raise CliError(str(error)) from None
    finally:
        session.close()
    if as_json:
        click.echo(farm.model_dump_json())
    else:
        print_status(farm)


def print_status(farm: BrokerStatus) -> None:
    console = Console()
    busy = sum(worker.busy for worker in farm.workers)
    console.print(
        f"up {farm.uptime_s:.0f} s · {len(farm.workers)} workers ({busy} busy) · "
        f"{farm.jobs_done} jobs done · {farm.jobs_per_s:.1f} jobs/s over the last minute · "
        f"{farm.requeued} requeued · {farm.rejected} rejected"
    )
    studies = Table("study", "queued", "running", "done", title="studies", title_justify="left")
    for study in farm.studies:
        studies.add_row(study.name, str(study.queued), str(study.leased), str(study.done))
    workers = Table("worker", "state", "job", "jobs done", title="workers", title_justify="left")
    for worker in farm.workers:
        state = "busy" if worker.busy else "idle"
        workers.add_row(worker.name, state, worker.job, str(worker.jobs_done))
    console.print(studies, workers)


@app.command()
@click.argument("directory", type=click.Path(path_type=Path))
@click.option(
    "--host",
    "hosts",
    multiple=True,
    default=DEFAULT_HOSTS,
    show_default=True,
    help="a name or address clients dial the broker by (repeat for several)",
)
@click.option("--days", type=click.IntRange(min=1), default=365, show_default=True)
@click.option(
    "--if-missing", is_flag=True, help="leave a complete set of credentials as it is (exit 0)"
)
def certs(directory: Path, hosts: tuple[str, ...], days: int, if_missing: bool) -> None:
    """Make development credentials for a secure farm: a CA, and a certificate and key for
    each role (broker, analytic, worker) whose common name is the role."""
    try:
        written = write_dev_credentials(directory, hosts, days, if_missing)
    except FileExistsError as error:
        raise CliError(str(error)) from None
    except OSError as error:
        raise CliError(f"cannot write {str(directory)!r}: {error.strerror}") from None
    if written:
        click.echo(
            f"wrote {len(written)} files to {directory}/; a host needs ca.pem and its role's"
        )
    else:
        click.echo(f"{directory}/ already holds a complete set of credentials; kept them")


@app.command()
def version() -> None:
    """Print the gainfarm version."""
    click.echo(package_version("gainfarm"))


def main() -> None:
    run_app(app, "broker")
