"""`worker`: a simulated cobot. Serve a farm (`start`), or run one episode by hand (`episode`)."""

# Light at the top (click and the shared options): MuJoCo, Zenoh and pydantic load inside the
# command that runs, so that `worker --help` and a refused option cost little more than click.

import math
from pathlib import Path
from typing import Any

import click

from gainfarm.cli import options
from gainfarm.cli.app import CliError, parse_numbers, program_group, run_app

# Held here, not imported, so that parsing and --help load nothing heavy (Zenoh, cryptography,
# pydantic): the most joints a robot may have (schemas.robot.MAX_JOINTS), which --kp and --kd
# are checked against before the robot is loaded (its own joint count, after).
MAX_JOINTS = 32


def gains(option: str, text: str, joints: int | None = None) -> tuple[float, ...]:
    """--kp's or --kd's gains, finite and non-negative, one per joint (`joints` of them, once
    the robot is known); or one line naming the option."""
    values = parse_numbers(option, text, joints)
    if len(values) > MAX_JOINTS:
        raise CliError(f"{option}: {len(values)} gains, more than any arm's {MAX_JOINTS} joints")
    if not all(math.isfinite(v) and v >= 0 for v in values):
        raise CliError(f"{option}: gains must be finite and non-negative, got {text!r}")
    return values


@program_group(__doc__)
def app() -> None:
    pass


@app.command(short_help="Simulate one PD episode; write its log, print its scores.")
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default="episode.mcap",
    show_default=True,
    help="where to write the MCAP episode log",
)
@options.robot("the arm the episode runs on")
@options.trajectory()
@options.duration()
@click.option(
    "--kp",
    help="one gain per joint of the robot, base to flange, N·m/rad  [default: the robot's "
    "default gains]",
)
@click.option(
    "--kd",
    help="one gain per joint of the robot, base to flange, N·m·s/rad  [default: the robot's "
    "default gains]",
)
@click.option(
    "--gains",
    "gains_file",
    type=click.Path(path_type=Path),
    help="the gains from a file instead of --kp/--kd: a controller from `analytic export` (JSON "
    'or YAML), or one {"kp": [...], "kd": [...]} object, a gain per joint of the robot',
)
@options.joints()
@options.plant()
@options.load()
@options.placement()
@click.option("--gravity-compensation", is_flag=True, help="add g(q_des) feed-forward to the PD")
@options.feedforward()
@click.option(
    "--as-tuned",
    is_flag=True,
    help="with --gains CONTROLLER: run it on the trajectory and plant it was tuned on (its run's "
    "first trajectory, its plant) instead of the options'",
)
@click.option("--json", "as_json", is_flag=True, help="print the scores as one JSON object")
def episode(**given: Any) -> None:
    """Simulate one PD episode on the arm --robot names (the iiwa 14 by default), write its MCAP
    log and print its scores. --center defaults to the robot's workspace centre, --duration to
    the kind's default on the robot: 5 s, or longer on an arm that needs it to stay within 90 %
    of its speed and acceleration limits (the Kinova Gen3's spiral and pyramid: 5.5 s)."""
    # What a parse can refuse, refused before the work's imports (the contract, MuJoCo).
    for option in ("kp", "kd"):
        if given[option] is not None:
            gains(f"--{option}", given[option])
    parse_numbers("--center", given["center"], 3)
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.worker.commands import episode as work

    work(**given)


@app.command(short_help="Serve a farm: run its jobs while free.")
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
@click.option(
    "--threads",
    type=click.IntRange(min=1, max=1024),
    help="threads stepping a batch's episodes, each on a core  [default: every core this "
    "process may use]",
)
@options.robot(
    "an arm to serve besides the installed ones, given by its description file (a worker "
    "serves every installed arm a job names)"
)
@options.log_level()
def start(**given: Any) -> None:
    """Serve a farm: ask the broker for jobs while free, run them, return their results. A job
    on an arm this worker lacks (neither installed nor --robot FILE) is refused with the reason.

    A job's episode log goes with its result if the job asks for it; else the worker keeps it
    in memory (--log-memory; the least recently used go first) for its study to fetch.

    SIGTERM or Ctrl-C: the job in progress is finished and returned, then the worker exits.
    """
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.worker.commands import start as work

    work(**given)


def main() -> None:
    run_app(app, "worker")
