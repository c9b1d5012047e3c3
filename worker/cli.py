"""`worker`: a simulated cobot. Serve a farm (`start`), or run one episode by hand (`episode`)."""

import logging
import math
import os
import re
import signal
import socket
import threading
from pathlib import Path

import click
from pydantic import ValidationError

from cli import options
from cli.app import CliError, parse_numbers, run_app, setup_logging
from cli.scores import show_scores
from models.dynamics import digest
from schemas.episode import EpisodeSpec
from schemas.gains import DEFAULT_GAINS, PDGains
from schemas.mcap_episode import write_episode
from schemas.objectives import score
from schemas.robot import N_JOINTS
from schemas.wire import NAME_PATTERN, NAME_RULE, describe
from worker.episode import run_episode
from worker.feedforward import ModelCache
from worker.ik import UnreachablePath
from worker.reference import InfeasibleReference
from worker.service import CobotWorker, NameTaken

DEFAULT_KP = ",".join(f"{gain:g}" for gain in DEFAULT_GAINS.kp)
DEFAULT_KD = ",".join(f"{gain:g}" for gain in DEFAULT_GAINS.kd)


@click.group(help=__doc__, no_args_is_help=True)
def app() -> None:
    pass


@app.command()
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default="episode.mcap",
    show_default=True,
    help="where to write the MCAP episode log",
)
@options.trajectory()
@options.duration()
@click.option("--kp", default=DEFAULT_KP, show_default=True, help="7 gains A1..A7, N·m/rad")
@click.option("--kd", default=DEFAULT_KD, show_default=True, help="7 gains A1..A7, N·m·s/rad")
@options.model()
@options.plant()
@options.placement()
@click.option("--gravity-compensation", is_flag=True, help="add g(q_des) feed-forward to the PD")
@options.feedforward()
@click.option("--json", "as_json", is_flag=True, help="print the scores as one JSON object")
def episode(
    out: Path,
    trajectory: str,
    duration: float,
    kp: str,
    kd: str,
    model: str,
    plant: str,
    trajectory_seed: int,
    center: str,
    size: float,
    gravity_compensation: bool,
    feedforward: Path | None,
    as_json: bool,
) -> None:
    """Simulate one PD episode on the iiwa 14, write its MCAP log and print its scores."""
    (path,) = options.trajectories([trajectory], duration, trajectory_seed, center, size)
    learned = options.feedforward_model(feedforward)
    if learned is not None and gravity_compensation:
        raise CliError(
            "--feedforward and --gravity-compensation exclude each other: "
            "an inverse-dynamics model already holds the arm against gravity"
        )
    try:
        spec = EpisodeSpec(
            gains=PDGains(kp=_gains("--kp", kp), kd=_gains("--kd", kd)),
            trajectory=path,
            model=options.model_spec(plant, model),
            gravity_compensation=gravity_compensation,
            feedforward=digest(learned[0]) if learned is not None else None,
        )
    except ValidationError as error:
        raise CliError(describe(error)) from None
    if not out.parent.is_dir():
        raise CliError(f"--out: directory {str(out.parent)!r} does not exist")
    try:
        log = run_episode(spec, learned[1] if learned is not None else None)
    except (UnreachablePath, InfeasibleReference) as error:
        raise CliError(str(error)) from None
    try:
        write_episode(log, out)
    except OSError as error:
        raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror}") from None
    show_scores(score(log), out, as_json)


@app.command()
@options.connect("the broker's Zenoh endpoint (repeat for several)")
@click.option(
    "--name",
    help="unique name of this cobot in the farm; with --tls, its identity's name  "
    "[default: HOST-PID; with --tls, the only worker identity in DIR]",
)
@options.tls(
    "a secure farm: directory with ca.pem and this worker's worker.NAME.pem and worker.NAME.key"
)
@click.option(
    "--model-cache",
    type=click.Path(path_type=Path),
    help="where fetched feed-forward models are kept  [default: $XDG_CACHE_HOME/gainfarm/models]",
)
@click.option(
    "--log-memory",
    type=click.IntRange(min=16),
    default=512,
    show_default=True,
    metavar="MIB",
    help="memory for the episode logs this worker keeps to be fetched (jobs that do not send "
    "their log), MiB",
)
@options.log_level()
def start(
    connect: tuple[str, ...],
    name: str | None,
    tls: Path | None,
    model_cache: Path | None,
    log_memory: int,
    log_level: str,
) -> None:
    """Serve a farm: ask the broker for jobs while free, run them, return their results.

    A job's episode log goes with its result if the job asks for it; else the worker keeps it
    in memory (--log-memory; the least recently used go first) for its study to fetch.

    SIGTERM or Ctrl-C: the job in progress is finished and returned, then the worker exits.
    """
    setup_logging("worker", log_level)
    # On a secure farm the router lets a worker lease only under its certificate's name.
    identity = options.identity(tls, "worker", name, name_option="--name")
    if identity is not None:
        name = identity.name
    name = name or re.sub(r"[^A-Za-z0-9_.\-]", "-", f"{socket.gethostname()}-{os.getpid()}")
    if not re.fullmatch(NAME_PATTERN, name):
        raise CliError(f"--name: {name!r} is not {NAME_RULE}")
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    log = logging.getLogger("gainfarm.worker")
    models = ModelCache(model_cache)  # one for the process: a reconnect keeps what it fetched
    waiting = False
    while not stop.is_set():
        try:
            cobot = CobotWorker(connect, name, identity, models, log_memory * 2**20)
        except (NameTaken, ValueError) as error:
            raise CliError(str(error)) from None
        except ConnectionError as error:
            if not waiting:  # a farm's workers often start before its broker
                log.warning("%s; retrying every second", error)
                waiting = True
            stop.wait(1.0)
            continue
        with cobot:
            log.info("worker %s serving %s", name, ", ".join(connect))
            done = cobot.serve(stop)
        log.info("worker %s stopped after %d jobs", name, done)


def _gains(option: str, text: str) -> tuple[float, ...]:
    values = parse_numbers(option, text, N_JOINTS)
    if not all(math.isfinite(v) and v >= 0 for v in values):
        raise CliError(f"{option}: gains must be finite and non-negative, got {text!r}")
    return values


def main() -> None:
    run_app(app, "worker")
