"""`broker`: the farm's Zenoh router and job scheduler (`start`), and a look at it (`status`)."""

import logging
import signal
import threading
from importlib.metadata import version as package_version

import click
from rich.console import Console
from rich.table import Table

from broker.service import DEFAULT_LISTEN, Broker
from broker.status import BrokerUnavailable, query_status
from schemas.errors import LOG_LEVELS, CliError, run_app, setup_logging
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
@click.option("--log-level", type=click.Choice(LOG_LEVELS), default="info", show_default=True)
def start(listen: tuple[str, ...], lease_seconds: float, log_level: str) -> None:
    """Route the farm and schedule its jobs until SIGTERM or Ctrl-C."""
    setup_logging("broker", log_level)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    try:
        broker = Broker(listen, lease_seconds=lease_seconds)
    except (ValueError, ConnectionError) as error:
        raise CliError(f"--listen: {error}") from None
    with broker:
        while not stop.wait(1.0):
            pass
    log.info("broker stopped after %d jobs", broker.queue.jobs_done)


@app.command()
@click.option(
    "--connect",
    multiple=True,
    default=["tcp/127.0.0.1:7447"],
    show_default=True,
    help="the broker's Zenoh endpoint",
)
@click.option("--json", "as_json", is_flag=True, help="print the status as one JSON object")
def status(connect: tuple[str, ...], as_json: bool) -> None:
    """Show the farm: workers, queue depth per study, throughput."""
    try:
        session = open_session("client", connect=connect)
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
def version() -> None:
    """Print the gainfarm version."""
    click.echo(package_version("gainfarm"))


def main() -> None:
    run_app(app, "broker")
