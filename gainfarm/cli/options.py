"""The options several commands share, each written once: same name, type, default and help.

A decorator per option (or group of options that always go together). The choices and defaults
come from where they are defined (the contract, schemas/), but only when they are needed: a
`Later` default or a `LazyChoice` loads its module when the option is processed or shown in
--help, never when a command's module is imported. So a command line is parsed, and a bad
value of another option refused, at the cost of `import click`.
"""

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from gainfarm import plugins
from gainfarm.cli.app import CliError, parse_numbers

if TYPE_CHECKING:
    from gainfarm.schemas.security import Role

F = TypeVar("F", bound=Callable[..., object])

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
LOG_LEVELS = ("debug", "info", "warning", "error")


class Later:
    """An option's default found when it is needed (the option processed without a value, or
    --help showing it), not when the command is defined: `default=Later(lambda: ...)`."""

    def __init__(self, value: Callable[[], Any]):
        self._value = value

    def __call__(self) -> Any:  # click calls a callable default for its value
        return self._value()

    def __str__(self) -> str:  # and shows a callable that is not a function by str()
        value = self._value()
        return ", ".join(map(str, value)) if isinstance(value, list | tuple) else str(value)


class LazyChoice(click.Choice):
    """A choice among names found when they are needed: a value to check, or --help to show
    (the trajectory kinds and optimisers plug-ins add: their metadata read, none imported)."""

    def __init__(self, names: Callable[[], Sequence[str]]):
        # Not Choice.__init__: it would read the names now. Not cached here either: what is
        # installed can change within a process (gainfarm.plugins caches until sys.path does).
        self._names = names
        self.case_sensitive = True

    @property
    def choices(self) -> Sequence[str]:  # type: ignore[override]
        return tuple(self._names())


class LaterHelp(click.Option):
    """An option whose help names values from a module too heavy to load for parsing: made when
    --help shows it. `click.option(..., cls=LaterHelp, later_help=lambda: ...)`."""

    def __init__(self, *args: Any, later_help: Callable[[], str], **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._later_help = later_help

    def get_help_record(self, ctx: click.Context) -> tuple[str, str] | None:
        self.help = self._later_help()
        return super().get_help_record(ctx)


def stack(*options: Callable[[F], F]) -> Callable[[F], F]:
    """Apply `options` so that they appear in --help in the order given."""

    def decorate(command: F) -> F:
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


# --- the trajectory -----------------------------------------------------------------------------


def trajectory_kinds() -> tuple[str, ...]:
    """The built-in kinds and the installed plug-ins' (their metadata read, none imported)."""
    return plugins.names(plugins.TRAJECTORIES)


# What --help shows and parsing falls back to, held here so that neither loads the contract
# (pydantic and NumPy, several times `import click`): TrajectorySpec()'s fields, the plants by
# name, PlantSpec's joints and RunConfig().model's name. tests/cli/test_held_defaults.py keeps
# each
# equal to the contract's.
TRAJECTORY_KIND = "spiral"
DURATION = 5.0
TRAJECTORY_SEED = 0
CENTER = (0.55, 0.0, 0.35)
SIZE = 0.08
PLANTS = ("realistic", "plain", "ideal")
PLANT = "realistic"
JOINTS = ("flexible", "rigid")
JOINT = "flexible"
ROBOT = "iiwa14"  # schemas.robot.DEFAULT_ROBOT


def trajectory(multiple: bool = False, help: str = "end-effector path") -> Callable[[F], F]:
    """--trajectory: one kind (parameter `trajectory`), or several (parameter `kinds`)."""
    return click.option(
        "--trajectory",
        "kinds" if multiple else "trajectory",
        multiple=multiple,
        type=LazyChoice(trajectory_kinds),
        default=[TRAJECTORY_KIND] if multiple else TRAJECTORY_KIND,
        show_default=True,
        help=help,
    )


def duration(help: str = "seconds") -> Callable[[F], F]:
    """--duration of the trajectory; its range is checked where the TrajectorySpec is made."""
    return click.option(
        "--duration",
        type=float,
        default=DURATION,
        show_default=True,
        help=help,
    )


def placement() -> Callable[[F], F]:
    """--trajectory-seed, --center and --size: where a trajectory lies and which one it is, so
    that datasets can cover the workspace."""
    return stack(
        click.option(
            "--trajectory-seed",
            type=click.IntRange(min=0),
            default=TRAJECTORY_SEED,
            show_default=True,
            help="which path of its kind: the random kind's waypoints, the fourier kind's "
            "coefficients, the spiral's and the pyramid's turn about the centre (0: unturned)",
        ),
        click.option(
            "--center",
            default=",".join(f"{v:g}" for v in CENTER),
            show_default=True,
            help="x,y,z of the path's centre in the base frame, m (not fourier)",
        ),
        click.option(
            "--size",
            type=float,
            default=SIZE,
            show_default=True,
            help="the path's half-width, m (not fourier)",
        ),
    )


# --- the simulated robot ------------------------------------------------------------------------


def joints(
    help: str | None = "the arm's joints: flexible (a spring between motor and link) or rigid",
) -> Callable[[F], F]:
    """--joints: the joints of the simulated arm, as PlantSpec names them (not --model: that word
    is the learned model's, `analytic learn --kind`)."""
    return click.option(
        "--joints",
        type=click.Choice(JOINTS),
        default=JOINT,
        show_default=True,
        help=help,
    )


class PlantChoice(LazyChoice):
    """A named plant, or a plant file (`analytic calibrate`'s twin): a name is checked as a
    choice, anything else must be a file, read where the spec is made (`model_spec`)."""

    name = "plant"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and value not in self.choices and Path(value).is_file():
            return value
        try:
            return super().convert(value, param, ctx)
        except click.BadParameter:
            self.fail(
                f"{value!r} is neither {', '.join(self.choices)} nor a plant file", param, ctx
            )

    def get_metavar(self, param: click.Parameter, ctx: click.Context | None = None) -> str:
        return f"[{'|'.join(self.choices)}|FILE]"


def plant(flag: str = "--plant", help: str | None = None) -> Callable[[F], F]:
    """--plant: the realistic plant (the default), another named one, or a plant file."""
    return click.option(
        flag,
        type=PlantChoice(lambda: PLANTS),
        default=PLANT,
        show_default=True,
        help=help
        or "realistic: behind KUKA's FRI torque interface (the robot adds gravity "
        "compensation from its own model), with friction, a 1-tick delay, encoders and torque "
        "sensors with noise, motor-side feedback; plain: the same without the robot's gravity "
        "compensation (the paper's plain PD); ideal: the paper's idealised plant; FILE: a plant "
        "file, such as the twin `analytic calibrate` writes",
    )


# Held here, not imported: parsing loads no schema (checked against schemas.robot in the tests).
RATED_PAYLOAD = 14.0  # kg, the data sheet's rated payload (schemas.robot.RATED_PAYLOAD)
MAX_LOAD_OFFSET = 0.5  # m (schemas.robot.MAX_LOAD_OFFSET)


def _payload(ctx: click.Context, param: click.Parameter, value: float | None) -> float | None:
    if value is not None and not 0 <= value <= RATED_PAYLOAD:  # NaN fails both
        raise CliError(
            f"--payload: {value:g} kg is not a load from 0 to the rated {RATED_PAYLOAD:g} kg"
        )
    return value


def _payload_com(
    ctx: click.Context, param: click.Parameter, value: str | None
) -> tuple[float, ...] | None:
    if value is None:
        return None
    com = parse_numbers("--payload-com", value, 3)
    if not all(abs(v) <= MAX_LOAD_OFFSET for v in com):  # NaN fails too
        raise CliError(
            f"--payload-com: {value!r}: each coordinate must be within {MAX_LOAD_OFFSET:g} m "
            "of the flange's centre"
        )
    return com


def load() -> Callable[[F], F]:
    """--payload and --payload-com: the load the robot is told (KUKA's load data), which its
    gravity model carries as the plant does; checked as the command line is parsed."""
    return stack(
        click.option(
            "--payload",
            type=float,
            metavar="KG",
            callback=_payload,
            help="the load at the flange the robot is told of (KUKA's load data): the plant "
            "holds it and the robot's gravity compensation carries it; robust tuning draws "
            "its error around it (models/uncertainty.toml)  [default: the plant's own told "
            "load: none for a named plant, a twin's calibrated one]",
        ),
        click.option(
            "--payload-com",
            metavar="X,Y,Z",
            callback=_payload_com,
            help="the told load's centre of mass in the flange frame, m (z along the flange's "
            "axis, away from the arm)  [default: 0,0,0, the flange's centre]",
        ),
    )


def check_load(payload: float | None, payload_com: tuple[float, ...] | None) -> None:
    """One line if --payload-com comes without --payload: a command calls it before its farm."""
    if payload_com is not None and payload is None:
        raise CliError("--payload-com: give the load's mass with --payload")


def feedforward(
    help: str = "add a learned inverse-dynamics model's torque for the reference "
    "to the PD (a directory from `analytic learn`, or its model.npz)",
) -> Callable[[F], F]:
    return click.option("--feedforward", type=click.Path(path_type=Path), help=help)


# --- the safety limits ---------------------------------------------------------------------------


def limits(
    help: str = "a JSON object of safety limits to check every episode against instead of the "
    'defaults, e.g. {"torque_step": 0.05, "chatter": null} (null: not checked; see '
    "docs/limits.md)",
) -> Callable[[F], F]:
    return click.option(
        "--limits", "limits_file", type=click.Path(path_type=Path), metavar="FILE", help=help
    )


def min_damping() -> Callable[[F], F]:
    return click.option(
        "--min-damping",
        type=float,
        metavar="Z",
        help="a constraint: every episode's closed loop, linearised along its reference, keeps "
        "a least damping ratio of at least Z (-1 to 1; 0: stable; see docs/limits.md)  "
        "[default: -0.1; a --limits file's min_damping null: not checked]",
    )


# --- the farm -------------------------------------------------------------------------------------


def connect(help: str) -> Callable[[F], F]:
    """--connect ENDPOINT (repeatable), the farm's broker on this host by default."""
    return click.option(
        "--connect", multiple=True, default=[DEFAULT_CONNECT], show_default=True, help=help
    )


def tls(help: str) -> Callable[[F], F]:
    """--tls DIR: the credentials of a secure farm (load them with `identity`)."""
    return click.option("--tls", type=click.Path(path_type=Path), help=help)


def participant(role: "Role") -> Callable[[F], F]:
    """--as NAME (parameter `participant`): which of a --tls directory's `role` identities to
    use; pass it to `identity`."""
    return click.option(
        "--as",
        "participant",
        metavar="NAME",
        help=f"with --tls: the {role} identity to use, by name  "
        f"[default: the only {role} identity in the directory]",
    )


def log_level() -> Callable[[F], F]:
    return click.option(
        "--log-level", type=click.Choice(LOG_LEVELS), default="info", show_default=True
    )


# --- the robot ----------------------------------------------------------------------------------


def robot(help: str = "the arm") -> Callable[[F], F]:
    """--robot NAME|FILE (parameter `robot`): a gainfarm.robots plug-in's name, or a robot
    description file (a user's own arm, docs/robot.md), which is read and registered in this
    process under the name it gives; the value is then that name."""
    return click.option(
        "--robot",
        "robot",
        default=ROBOT,
        show_default=True,
        metavar="NAME|FILE",
        callback=_robot,
        help=f"{help}: a robot's name (iiwa14, the built-in arms and installed plug-ins: "
        "`analytic plugins`), or a robot description file (.toml) of your own arm",
    )


def _robot(ctx: click.Context, param: click.Parameter, value: str) -> str:
    names = plugins.names(plugins.ROBOTS)
    if value in names:
        return value
    if Path(value).suffix == ".toml" or Path(value).is_file():
        # start-up: MuJoCo and the contract load only when a description file is given
        from gainfarm.models.described import register_file
        from gainfarm.schemas.robot_file import BadRobotFile

        try:
            return register_file(Path(value))
        except BadRobotFile as error:
            raise CliError(f"--robot: {value}: {error}") from None
    raise click.BadParameter(
        f"{value!r} is no robot here (these are: {', '.join(names)}) and no description file",
        param_hint="'--robot'",
    )
