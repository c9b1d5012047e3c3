"""`broker`: the farm's Zenoh router and job scheduler (`start`), a look at it (`status`), and
development credentials for a secure farm (`certs`)."""

# Light at the top (click and the shared options): Zenoh, rich and the certificates' cryptography
# load inside the command that runs, so that `broker --help` costs little more than click.

import logging
import re
import signal
import threading
import time
from contextlib import nullcontext
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import click

from gainfarm.cli import interrupts, options
from gainfarm.cli.app import CliError, program_group, run_app, setup_logging

if TYPE_CHECKING:
    import zenoh
    from rich.console import Group

    from gainfarm.schemas.security import Role
    from gainfarm.schemas.wire import BrokerStatus

log = logging.getLogger("gainfarm.broker")


@program_group(__doc__)
def app() -> None:
    pass


def _default(module: str, name: str) -> Any:
    """A default the broker's own modules define, loaded when it is needed."""
    from importlib import import_module

    return getattr(import_module(f"gainfarm.broker.{module}"), name)


@app.command()
@click.option(
    "--listen",
    multiple=True,
    default=options.Later(lambda: [_default("service", "DEFAULT_LISTEN")]),
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
    default=options.Later(lambda: _default("queue", "DEFAULT_MAX_QUEUED")),
    show_default=True,
    help="jobs queued in all studies together; more are deferred (submitted again later)",
)
@click.option(
    "--max-queued-per-study",
    type=click.IntRange(min=1),
    default=options.Later(lambda: _default("queue", "DEFAULT_MAX_QUEUED_PER_STUDY")),
    show_default=True,
    help="jobs queued in one study; more are deferred",
)
@click.option(
    "--submit-rate",
    type=click.FloatRange(min=0, min_open=True),
    help="jobs per second a study may submit (bursts of 10 s worth)  [default: no limit]",
)
@options.log_level()
def start(
    listen: tuple[str, ...],
    lease_seconds: float,
    tls: Path | None,
    max_queued: int,
    max_queued_per_study: int,
    submit_rate: float | None,
    log_level: str,
) -> None:
    """Route the farm and schedule its jobs until SIGTERM or Ctrl-C."""
    from gainfarm.broker.service import Broker
    from gainfarm.schemas.security import participants

    setup_logging("broker", log_level)
    identity = values.identity(tls, "broker")
    if identity is not None:
        # The access policy is fixed when the router opens: say whom it lets in.
        allowed = participants(identity.directory)
        names = ", ".join(participant.common_name for participant in allowed) or "nobody"
        log.info("secure profile: %s may use the farm", names)
        if not allowed:
            log.warning("no participant certificates in %s: only the broker may do anything", tls)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    try:
        broker = Broker(
            listen,
            lease_seconds=lease_seconds,
            identity=identity,
            max_queued=max_queued,
            max_queued_per_study=max_queued_per_study,
            submit_rate=submit_rate,
        )
    except (ValueError, ConnectionError) as error:
        raise CliError(f"--listen: {error}") from None
    with broker:
        while not stop.wait(1.0):
            pass
    log.info("broker stopped after %d jobs", broker.queue.jobs_done)


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
def status(
    connect: tuple[str, ...],
    tls: Path | None,
    who: str,
    as_json: bool,
    watch: bool,
    interval: float,
) -> None:
    """Show the farm: workers, queue depth per study, throughput."""
    from rich.console import Console

    from gainfarm.edges.transport import open_session
    from gainfarm.schemas.security import ROLES

    role, _, name = who.partition(".")
    if role not in ROLES:
        raise CliError(f"--as: {who!r} is not broker, analytic[.NAME] or worker[.NAME]")
    identity = values.identity(tls, cast("Role", role), name or None, name_option="--as")
    try:
        session = open_session("client", connect=connect, identity=identity)
    except (ValueError, ConnectionError) as error:
        raise CliError(f"--connect: {error}") from None
    try:
        farm = _look(session)
        if not watch:
            if as_json:
                click.echo(farm.model_dump_json())
            else:
                Console().print(status_view(farm))
            return
        _watch(session, farm, as_json, interval)
    finally:
        session.close()


def _look(session: "zenoh.Session") -> "BrokerStatus":
    from gainfarm.broker.status import BrokerUnavailable, query_status
    from gainfarm.schemas.wire import BadMessage

    try:
        return query_status(session, timeout=5.0)
    except (BrokerUnavailable, BadMessage) as error:
        raise CliError(f"--connect: {error}") from None


def _watch(session: "zenoh.Session", farm: "BrokerStatus", as_json: bool, interval: float) -> None:
    """`broker status --watch`: until Ctrl-C. A broker that stops answering is said so, and
    asked again at the next look."""
    from rich.console import Console
    from rich.live import Live
    from rich.text import Text

    console = Console()
    redrawn = console.is_terminal and not as_json
    screen = Live(status_view(farm), console=console, auto_refresh=False) if redrawn else None
    with screen or nullcontext():
        shown: BrokerStatus | str = farm
        while True:
            if screen is None:
                if isinstance(shown, str):
                    click.echo(shown, err=True)
                else:
                    click.echo(shown.model_dump_json() if as_json else summary(shown))
            time.sleep(interval)
            interrupts.check()
            try:
                shown = _look(session)
            except CliError as error:
                shown = error.format_message()
            if screen is not None:
                screen.update(
                    Text(shown) if isinstance(shown, str) else status_view(shown), refresh=True
                )


def summary(farm: "BrokerStatus") -> str:
    """The farm in one line."""
    from gainfarm.cli.words import counted

    return (
        f"up {farm.uptime_s:.0f} s · {counted(farm.worker_count, 'worker')} ({farm.busy} busy) · "
        f"{counted(farm.study_count, 'study')} · "
        f"{farm.queued} queued · {counted(farm.jobs_done, 'job')} done · "
        f"{farm.jobs_per_s:.1f} jobs/s over the last minute · "
        f"{farm.requeued} requeued · {farm.rejected} rejected"
    )


def status_view(farm: "BrokerStatus") -> "Group":
    """The farm as a person reads it: the summary line, its studies and its workers."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    studies = Table(
        "study",
        "queued",
        "running",
        "done",
        title=_listed("studies", farm.studies, farm.study_count),
    )
    for study in farm.studies:
        studies.add_row(study.name, str(study.queued), str(study.leased), str(study.done))
    workers = Table(
        "worker",
        "state",
        "job",
        "jobs done",
        title=_listed("workers", farm.workers, farm.worker_count),
    )
    for worker in farm.workers:
        state = "busy" if worker.busy else "idle"
        workers.add_row(worker.name, state, worker.job, str(worker.jobs_done))
    studies.title_justify = workers.title_justify = "left"
    return Group(Text(summary(farm)), studies, workers)


def _listed(what: str, listed: list, total: int) -> str:
    """A table's title: the status lists the first few of many (it must stay a small message)."""
    return what if len(listed) == total else f"{what} (the first {len(listed)} of {total})"


@app.command(short_help="Make development credentials for a secure farm.")
@click.argument("directory", type=click.Path(path_type=Path))
@click.option(
    "--analytic",
    "analytics",
    multiple=True,
    metavar="NAME",
    cls=options.LaterHelp,
    later_help=lambda: (
        "issue an analytic participant's identity (its studies are named NAME.*); "
        "repeat for several  [default with a new CA: "
        f"{', '.join(_default('certs', 'DEFAULT_ANALYTICS'))}]"
    ),
)
@click.option(
    "--worker",
    "workers",
    multiple=True,
    metavar="NAME",
    cls=options.LaterHelp,
    later_help=lambda: (
        "issue a worker's identity (it serves as `worker start --name NAME`); "
        "repeat for several  [default with a new CA: "
        f"{', '.join(_default('certs', 'DEFAULT_WORKERS'))}]"
    ),
)
@click.option(
    "--host",
    "hosts",
    multiple=True,
    default=options.Later(lambda: _default("certs", "DEFAULT_HOSTS")),
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
def certs(
    directory: Path,
    analytics: tuple[str, ...],
    workers: tuple[str, ...],
    hosts: tuple[str, ...],
    days: int,
    if_missing: bool,
    revoke: tuple[str, ...],
) -> None:
    """Make development credentials for a secure farm: a CA, the broker's certificate and key,
    and one per participant, whose common name is ROLE.NAME (analytic.alice, worker.cobot-3).
    Run again on the same DIR, it adds the participants named, signed by the same CA."""
    from gainfarm.broker.certs import write_dev_credentials
    from gainfarm.schemas.security import PARTICIPANT_RULE, is_participant_name

    if revoke:
        if analytics or workers:
            raise CliError("--revoke: revoke and issue in separate runs")
        _revoke(directory, revoke)
        return
    for option, names in (("--analytic", analytics), ("--worker", workers)):
        for name in names:
            if not is_participant_name(name):
                raise CliError(f"{option}: {name!r} is not a participant name: {PARTICIPANT_RULE}")
    for host in hosts:
        if not _is_host(host):
            # Else written into the broker's certificate, and every TLS client refused later.
            raise CliError(f"--host: {host!r} is neither a host name nor an IP address")
    if directory.exists() and not directory.is_dir():
        raise CliError(f"DIR: {str(directory)!r} is a file, not a directory")
    try:
        issued = write_dev_credentials(directory, hosts, days, if_missing, analytics, workers)
    except FileExistsError as error:
        raise CliError(str(error)) from None
    except OSError as error:
        raise CliError(f"DIR: cannot write {str(directory)!r}: {error.strerror}") from None
    except ValueError as error:
        raise CliError(str(error)) from None
    made = sorted({path.stem for path in issued.written} - {"ca"})
    if made:
        click.echo(
            f"wrote {len(issued.written)} files to {directory}/ ({', '.join(made)}); every host "
            "needs ca.pem and its own NAME.pem and NAME.key, and the broker's host also needs "
            "every participant's .pem"
        )
    else:
        click.echo(f"{directory}/ already holds those credentials; kept them")


# A DNS name: dot-separated labels of letters, digits and inner hyphens, 253 characters at most;
# underscores too, as container service names have them (TLS clients accept them).
_HOST_LABEL = r"[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?"
_HOST_NAME = re.compile(rf"(?=.{{1,253}}$){_HOST_LABEL}(?:\.{_HOST_LABEL})*\.?")


def _is_host(host: str) -> bool:
    """Whether `host` can stand in a certificate's subject alternative names."""
    import ipaddress

    try:
        ipaddress.ip_address(host)
    except ValueError:
        return _HOST_NAME.fullmatch(host) is not None
    return True


def _revoke(directory: Path, revoke: tuple[str, ...]) -> None:
    from gainfarm.broker.certs import revoke as revoke_identity

    for who in revoke:
        try:
            identity = revoke_identity(directory, who)
        except ValueError as error:
            raise CliError(f"--revoke: {error}") from None
        except OSError as error:
            raise CliError(f"cannot write {str(directory)!r}: {error.strerror}") from None
        click.echo(
            f"revoked {identity.common_name}; restart the broker to lock it out "
            "(delete its .pem there too if the broker keeps its credentials elsewhere)"
        )


@app.command()
def version() -> None:
    """Print the gainfarm version."""
    from importlib.metadata import version as package_version

    click.echo(package_version("gainfarm"))


def main() -> None:
    run_app(app, "broker")
