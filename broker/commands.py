"""What `broker`'s commands do once they run, one function each (the command line, broker/cli.py,
imports this module when a command runs: its imports here are the work's)."""

import logging
import signal
import threading
import time
from contextlib import nullcontext
from importlib.metadata import version as package_version
from pathlib import Path
from typing import TYPE_CHECKING, cast

import click
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from gainfarm.broker.cli import is_host
from gainfarm.cli import interrupts, values
from gainfarm.cli.app import CliError, setup_logging
from gainfarm.cli.words import counted
from gainfarm.schemas.security import PARTICIPANT_RULE, ROLES, is_participant_name, participants
from gainfarm.schemas.wire import BadMessage

log = logging.getLogger("gainfarm.broker")

if TYPE_CHECKING:
    import zenoh
    from rich.console import Group

    from gainfarm.schemas.security import Role
    from gainfarm.schemas.wire import BrokerStatus


def start(
    listen: tuple[str, ...],
    lease_seconds: float,
    tls: Path | None,
    max_queued: int,
    max_queued_per_study: int,
    submit_rate: float | None,
    log_level: str,
) -> None:
    """`broker start` with its options as parsed (broker/cli.py)."""
    setup_logging("broker", log_level)
    identity = values.identity(tls, "broker")
    if identity is not None:
        # The access policy is fixed when the router opens: say whom it lets in.
        allowed = participants(identity.directory)
        names = ", ".join(participant.common_name for participant in allowed) or "nobody"
        log.info("secure profile: %s may use the farm", names)
        if not allowed:
            log.warning("no participant certificates in %s: only the broker may do anything", tls)
    # start-up: Zenoh loads once the options are checked
    from gainfarm.broker.service import Broker

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


def status(
    connect: tuple[str, ...],
    tls: Path | None,
    who: str,
    as_json: bool,
    watch: bool,
    interval: float,
) -> None:
    """`broker status` with its options as parsed (broker/cli.py)."""
    role, _, name = who.partition(".")
    if role not in ROLES:
        raise CliError(f"--as: {who!r} is not broker, analytic[.NAME] or worker[.NAME]")
    identity = values.identity(tls, cast("Role", role), name or None, name_option="--as")
    # start-up: Zenoh loads once the options are checked
    from gainfarm.edges.transport import open_session

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
    # start-up: Zenoh, as in `status`
    from gainfarm.broker.status import BrokerUnavailable, query_status

    try:
        return query_status(session, timeout=5.0)
    except (BrokerUnavailable, BadMessage) as error:
        raise CliError(f"--connect: {error}") from None


def _watch(session: "zenoh.Session", farm: "BrokerStatus", as_json: bool, interval: float) -> None:
    """`broker status --watch`: until Ctrl-C. A broker that stops answering is said so, and
    asked again at the next look."""
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
    return (
        f"up {farm.uptime_s:.0f} s · {counted(farm.worker_count, 'worker')} ({farm.busy} busy) · "
        f"{counted(farm.study_count, 'study')} · "
        f"{farm.queued} queued · {counted(farm.jobs_done, 'job')} done · "
        f"{farm.jobs_per_s:.1f} jobs/s over the last minute · "
        f"{farm.requeued} requeued · {farm.rejected} rejected"
    )


def status_view(farm: "BrokerStatus") -> "Group":
    """The farm as a person reads it: the summary line, its studies and its workers."""
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


def certs(
    directory: Path,
    analytics: tuple[str, ...],
    workers: tuple[str, ...],
    hosts: tuple[str, ...],
    days: int,
    if_missing: bool,
    revoke: tuple[str, ...],
) -> None:
    """`broker certs` with its options as parsed (broker/cli.py)."""
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
        if not is_host(host):
            # Else written into the broker's certificate, and every TLS client refused later.
            raise CliError(f"--host: {host!r} is neither a host name nor an IP address")
    if directory.exists() and not directory.is_dir():
        raise CliError(f"DIR: {str(directory)!r} is a file, not a directory")
    # start-up: cryptography loads once the options are checked
    from gainfarm.broker.certs import write_dev_credentials

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
def _revoke(directory: Path, revoke: tuple[str, ...]) -> None:
    # start-up: cryptography, as in `certs`
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


def version() -> None:
    """`broker version` with its options as parsed (broker/cli.py)."""
    click.echo(package_version("gainfarm"))
