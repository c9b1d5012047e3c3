"""What several `analytic` commands declare: the options of a run and of the farm, and the
one-line errors that need nothing but the options. Light: click, the plug-in registry and the
run's defaults; what the options are made into when a command runs is work/common.py's."""

from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import click
from click.core import ParameterSource

from gainfarm import plugins
from gainfarm.analytic.tuning import defaults
from gainfarm.cli import options
from gainfarm.cli.app import CliError, parse_numbers

F = TypeVar("F", bound=Callable[..., object])


def pop_option() -> Callable[[F], F]:
    return click.option(
        "--pop",
        type=click.IntRange(min=defaults.POP_MIN, max=defaults.POP_MAX),
        default=defaults.POP,
        show_default=True,
        help="population size",
    )


def termination_options(per_run: bool = False) -> Callable[[F], F]:
    """--generations and --evaluations (which exclude each other: RunConfig says so)."""
    when = "per run, instead of converging: " if per_run else ""
    return options.stack(
        click.option(
            "--generations",
            type=click.IntRange(min=defaults.GENERATIONS_MIN),
            help=f"{when}stop after N generations",
        ),
        click.option(
            "--evaluations",
            type=click.IntRange(min=defaults.EVALUATIONS_MIN),
            help=f"{when}stop after N evaluations",
        ),
    )


# Where the farm is, the same for every command that uses one.
farm_options = options.stack(
    click.option("--connect", multiple=True, help="a running broker's Zenoh endpoint"),
    options.tls("a secure farm: directory with ca.pem and an analytic participant's pair"),
    click.option(
        "--as",
        "participant",
        help="with --tls: the analytic participant to be, if DIR holds several",
    ),
    click.option(
        "--local", is_flag=True, help="run the farm here: a broker process and worker processes"
    ),
    click.option(
        "--workers",
        type=click.IntRange(min=1, max=64),
        help="with a local farm: how many worker processes (they share the cores: each steps "
        "its episodes on cores / N threads)  [default: one per core]",
    ),
)


def robustness() -> Callable[[F], F]:
    """--plants K, --aggregate and --uncertainty FILE: robust tuning over plant variants."""
    return options.stack(
        click.option(
            "--plants",
            type=click.IntRange(0, 64),
            default=defaults.PLANTS,
            show_default=True,
            metavar="K",
            help="robust tuning: score every candidate on the nominal plant and K variants, the "
            "designed corners first (the heavy and the light arm), then random "
            "draws from the uncertainty ranges, the same for every candidate; constraints hold "
            "on every one (0: the nominal plant alone)",
        ),
        click.option(
            "--aggregate",
            type=click.Choice(("mean", "worst", "cvar")),
            default=defaults.AGGREGATE,
            show_default=True,
            help="each trajectory's objectives over its plants, each objective apart: the mean, "
            "the worst (a bound on every plant), or the mean of the worst quarter",
        ),
        click.option(
            "--check-plants",
            type=click.IntRange(0, 256),
            default=64,
            show_default=True,
            metavar="M",
            help="once the run ends, run the controllers it names and the default gains on M "
            "held-out plants drawn from the same ranges (check.json; 0: no check)",
        ),
        uncertainty(
            "the ranges the variants are drawn from, a TOML file in the form of the shipped "
            "models/uncertainty.toml (its defaults, each with its source)"
        ),
    )


bag_topics = options.stack(
    click.option(
        "--joint-states",
        default="/joint_states",
        show_default=True,
        help="a bag's sensor_msgs/JointState topic of the measured angles, velocities and torques",
    ),
    click.option(
        "--commands",
        default="/joint_commands",
        show_default=True,
        help="a bag's JointState topic whose effort is the torque the controller sent",
    ),
    click.option(
        "--motor-states",
        default="/motor_states",
        show_default=True,
        help="a bag's JointState topic of the motor angles, if the arm logs them (the joint "
        "stiffness needs them)",
    ),
)


def uncertainty(help: str) -> Callable[[F], F]:
    """--uncertainty FILE, the plant ranges (parameter `uncertainty_file`)."""
    return click.option(
        "--uncertainty",
        "uncertainty_file",
        type=click.Path(path_type=Path),
        metavar="FILE",
        help=help,
    )


RUN_FILE = "config.json"  # what says a run is in a directory (tuning.records.CONFIG_JSON)
# The file options a command may take, each checked readable before the contract loads.
FILES = {
    "limits_file": "--limits",
    "uncertainty_file": "--uncertainty",
    "gains_file": "--gains",
}


def unless_default(given: dict, *names: str) -> dict:
    """`given` with each of the options `names` None where the command line left it at its
    default: what the work then takes from the robot (--center: its workspace's centre)."""
    context = click.get_current_context()
    left = {
        name: None
        for name in names
        if context.get_parameter_source(name) is click.ParameterSource.DEFAULT
    }
    return given | left


def prechecked(given: dict, runs: str | None = None) -> None:
    """What a parse or a stat can refuse of a command's options, refused before its work is
    imported (the contract's pydantic and NumPy, then MuJoCo, Zenoh, pymoo): the farm options'
    rules, --center's three numbers, a file option's file that cannot be opened, a run
    directory (parameter `runs`: one, or a tuple of them) that holds no run. The same
    line the work would say; what only the contract can judge (a limit's value), it judges."""
    if "connect" in given and "local" in given:
        farm_rules(given)
    if isinstance(given.get("center"), str):
        parse_numbers("--center", given["center"], 3)
    named = given[runs] if runs is not None else ()
    for run_dir in named if isinstance(named, tuple) else (named,):
        if not (run_dir / RUN_FILE).is_file():
            raise CliError(f"{str(run_dir)!r} holds no run (no {RUN_FILE})")
    for name, option in FILES.items():
        path = given.get(name)
        if path is None:
            continue
        try:
            with open(path, "rb"):
                pass
        except OSError as error:
            raise CliError(f"{option}: cannot read {str(path)!r}: {error.strerror}") from None


def farm_rules(given: dict) -> None:
    """The farm options' rules (farm_options), checked before a command imports its work: one
    line naming the option that breaks one."""
    connect, local, tls = given["connect"], given["local"], given["tls"]
    if connect and local:
        raise CliError("--connect and --local exclude each other")
    if tls is not None and not connect:
        raise CliError("--tls needs --connect: a local farm is this user's alone, without TLS")
    if given["participant"] is not None and tls is None:
        raise CliError("--as needs --tls: a participant is a secure farm's identity")


def farm_problem(connect: tuple[str, ...], error: Exception) -> str:
    """Why the farm cannot be had, in one line naming the option that chose it."""
    return f"{'--connect' if connect else 'local farm'}: {error}"


def start_option(part: str, duration: str = "--duration") -> str:
    """The option that says the part of a run `tune.CannotStart` names."""
    return {"duration": duration, "placement": "--center/--size"}.get(part, f"--{part}")


def refuse_under_a_file(directory: Path, option: str) -> None:
    """Refuse, before anything runs, a directory to be made under a file: mkdir would say only
    "File exists" or "Not a directory", and after the work it was to hold."""
    if directory.exists():
        if not directory.is_dir():
            raise CliError(f"{option}: {str(directory)!r} is a file, not a directory")
        return
    ancestor = next((parent for parent in directory.parents if parent.exists()), None)
    if ancestor is not None and not ancestor.is_dir():
        raise CliError(f"{option}: cannot write {str(directory)!r}: {str(ancestor)!r} is a file")


def unwritable(error: OSError, then: str) -> CliError:
    """A file of a run that could not be written (disk full, read-only, no permission), in one
    line: the files are each whole or absent and the checkpoint is the last good one, so once
    the cause is gone the run goes on as `then` says."""
    where = f" {str(error.filename)!r}" if error.filename else ""
    return CliError(f"cannot write{where}: {error.strerror or error}; once it can, {then}")


def algorithm_names() -> tuple[str, ...]:
    """The optimisers a run may name: the built-in ones and the installed plug-ins' (their
    metadata read, none imported, so pymoo does not load to parse a command line)."""
    return plugins.names(plugins.ALGORITHMS)


def robot_read(what: str, help: str | None = None, default: str | None = None) -> Callable[[F], F]:
    """--robot NAME|FILE (options.robot) on a command that reads the arm from its input
    (`what`: "the run", "the log", "the twin"): left out, the arm is the input's, and the
    parameter is None; given, the input must be of that arm (a FILE registers one's own arm,
    so that its input can be read at all). `help` and `default` say it otherwise."""

    def decorate(command: F) -> F:
        command = options.robot(help=help or f"the arm {what} is of")(command)
        option = command.__click_params__[-1]  # type: ignore[attr-defined]  # click's list
        option.show_default = default or f"{what}'s"
        named = option.callback

        def given(ctx: click.Context, param: click.Parameter, value: str) -> str | None:
            name = named(ctx, param, value) if named is not None else value
            left_out = ctx.get_parameter_source(param.name or "") is ParameterSource.DEFAULT
            return None if left_out else name

        option.callback = given
        return command

    return decorate
