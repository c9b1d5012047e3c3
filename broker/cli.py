"""`broker`: the farm's Zenoh router and job scheduler (`start`), a look at it (`status`), and
development credentials for a secure farm (`certs`)."""

# Light at the top (click and the shared options): Zenoh, rich and the certificates' cryptography
# load inside the command that runs, so that `broker --help` costs little more than click.

import ipaddress
import re
from pathlib import Path
from typing import Any

import click

from gainfarm.cli import options
from gainfarm.cli.app import CliError, program_group, run_app

_HOST_LABEL = r"[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?"
_HOST_NAME = re.compile(rf"(?=.{{1,253}}$){_HOST_LABEL}(?:\.{_HOST_LABEL})*\.?")


def is_host(host: str) -> bool:
    """Whether `host` can stand in a certificate's subject alternative names."""
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return _HOST_NAME.fullmatch(host) is not None
    return True


@program_group(__doc__)
def app() -> None:
    pass


# Held here, not imported, so that parsing and --help load nothing heavy (Zenoh, cryptography,
# pydantic): tests/cli/test_held_defaults.py keeps each equal to its source's.
LISTEN = "tcp/0.0.0.0:7447"  # broker.service.DEFAULT_LISTEN
MAX_QUEUED, MAX_QUEUED_PER_STUDY = 100_000, 20_000  # broker.queue's DEFAULT_MAX_QUEUED...
# broker.certs's DEFAULT_ANALYTICS, DEFAULT_WORKERS and DEFAULT_HOSTS
ANALYTICS, WORKERS, HOSTS = ("dev",), ("cobot-1",), ("localhost", "127.0.0.1")


@app.command()
@click.option(
    "--listen",
    multiple=True,
    default=[LISTEN],
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
    "secure profile: TLS with client certificates and per-participant access control; "
    "directory with ca.pem, broker.pem, broker.key and the certificate of every participant "
    "let in (see `broker certs`)"
)
@click.option(
    "--max-queued",
    type=click.IntRange(min=1),
    default=MAX_QUEUED,
    show_default=True,
    help="jobs queued in all studies together; more are deferred (submitted again later)",
)
@click.option(
    "--max-queued-per-study",
    type=click.IntRange(min=1),
    default=MAX_QUEUED_PER_STUDY,
    show_default=True,
    help="jobs queued in one study; more are deferred",
)
@click.option(
    "--submit-rate",
    type=click.FloatRange(min=0, min_open=True),
    help="jobs per second a study may submit (bursts of 10 s worth)  [default: no limit]",
)
@options.log_level()
def start(**given: Any) -> None:
    """Route the farm and schedule its jobs until SIGTERM or Ctrl-C."""
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.broker.commands import start as work

    work(**given)


@app.command()
@options.connect("the broker's Zenoh endpoint")
@options.tls("a secure farm: directory with ca.pem and the broker's (or a participant's) pair")
@click.option(
    "--as",
    "who",
    default="broker",
    show_default=True,
    help="with --tls: whose credentials to use: broker, a role (its only identity in the "
    "directory), or a participant, role.NAME (e.g. worker.cobot-1)",
)
@click.option(
    "--json", "as_json", is_flag=True, help="print the status as one JSON object (a line each)"
)
@click.option(
    "--watch",
    is_flag=True,
    help="look again every --interval until Ctrl-C (exit status 130): on a terminal the view "
    "is redrawn in place, elsewhere a line is printed each time",
)
@click.option(
    "--interval",
    type=click.FloatRange(min=0.1),
    default=2.0,
    show_default=True,
    help="with --watch: seconds between looks",
)
def status(**given: Any) -> None:
    """Show the farm: workers, queue depth per study, throughput."""
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.broker.commands import status as work

    work(**given)


@app.command(short_help="Make development credentials for a secure farm.")
@click.argument("directory", type=click.Path(path_type=Path))
@click.option(
    "--analytic",
    "analytics",
    multiple=True,
    metavar="NAME",
    help="issue an analytic participant's identity (its studies are named NAME.*); "
    f"repeat for several  [default with a new CA: {', '.join(ANALYTICS)}]",
)
@click.option(
    "--worker",
    "workers",
    multiple=True,
    metavar="NAME",
    help="issue a worker's identity (it serves as `worker start --name NAME`); "
    f"repeat for several  [default with a new CA: {', '.join(WORKERS)}]",
)
@click.option(
    "--host",
    "hosts",
    multiple=True,
    default=list(HOSTS),
    show_default=True,
    help="a name or address clients dial the broker by (repeat for several)",
)
@click.option(
    "--days",
    type=click.IntRange(min=1),
    default=365,
    show_default=True,
    help="how long the certificates issued now are valid",
)
@click.option(
    "--if-missing",
    is_flag=True,
    help="keep the identities already there and issue only the missing ones (exit 0)",
)
@click.option(
    "--revoke",
    multiple=True,
    metavar="ROLE.NAME",
    help="revoke an identity (worker.cobot-3, or a name only one participant has): it is "
    "denied everything once the broker restarts, and its name is never issued again",
)
def certs(**given: Any) -> None:
    """Make development credentials for a secure farm: a CA, the broker's certificate and key,
    and one per participant, whose common name is ROLE.NAME (analytic.alice, worker.cobot-3).
    Run again on the same DIR, it adds the participants named, signed by the same CA."""
    for host in given["hosts"]:  # before the work's imports: the contract, cryptography
        if not is_host(host):
            # Else written into the broker's certificate, and every TLS client refused later.
            raise CliError(f"--host: {host!r} is neither a host name nor an IP address")
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.broker.commands import certs as work

    work(**given)


@app.command()
def version(**given: Any) -> None:
    """Print the gainfarm version."""
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.broker.commands import version as work

    work(**given)


def main() -> None:
    run_app(app, "broker")
