"""The options several commands share, each written once: same name, type, default and help.

A decorator per option (or group of options that always go together). The choices and defaults
come from where they are defined (the contract, schemas/), but only when they are needed: a
`Later` default or a `LazyChoice` loads its module when the option is processed or shown in
--help, never when a command's module is imported. So a command line is parsed, and a bad
value of another option refused, at the cost of `import click`.
"""

import functools
import typing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from gainfarm import plugins
from gainfarm.cli.app import CliError, parse_numbers

if TYPE_CHECKING:
    from gainfarm.models.dynamics import DynamicsModel
    from gainfarm.schemas.limits import Limits
    from gainfarm.schemas.plant_file import PlantFile
    from gainfarm.schemas.robot import ModelSpec
    from gainfarm.schemas.security import Role, TlsIdentity
    from gainfarm.schemas.trajectory import TrajectorySpec

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
    from gainfarm import plugins

    return plugins.names(plugins.TRAJECTORIES)


@functools.cache
def _trajectory() -> "TrajectorySpec":
    """The default trajectory: where every trajectory option's default comes from."""
    from gainfarm.schemas.trajectory import TrajectorySpec

    return TrajectorySpec()


def trajectory(multiple: bool = False, help: str = "end-effector path") -> Callable[[F], F]:
    """--trajectory: one kind (parameter `trajectory`), or several (parameter `kinds`)."""
    kind = Later(lambda: str(_trajectory().kind))
    return click.option(
        "--trajectory",
        "kinds" if multiple else "trajectory",
        multiple=multiple,
        type=LazyChoice(trajectory_kinds),
        default=Later(lambda: [kind()]) if multiple else kind,
        show_default=True,
        help=help,
    )


def duration(help: str = "seconds") -> Callable[[F], F]:
    """--duration of the trajectory; its range is checked where the TrajectorySpec is made."""
    return click.option(
        "--duration",
        type=float,
        default=Later(lambda: _trajectory().duration),
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
            default=Later(lambda: _trajectory().seed),
            show_default=True,
            help="which path of its kind: the random kind's waypoints, the fourier kind's "
            "coefficients, the spiral's and the pyramid's turn about the centre (0: unturned)",
        ),
        click.option(
            "--center",
            default=Later(lambda: ",".join(f"{v:g}" for v in _trajectory().center)),
            show_default=True,
            help="x,y,z of the path's centre in the base frame, m (not fourier)",
        ),
        click.option(
            "--size",
            type=float,
            default=Later(lambda: _trajectory().size),
            show_default=True,
            help="the path's half-width, m (not fourier)",
        ),
    )


_FIELD_OPTIONS = {
    "kind": "--trajectory",
    "duration": "--duration",
    "seed": "--trajectory-seed",
    "center": "--center",
    "size": "--size",
}


def trajectories(
    kinds: typing.Iterable[str], duration: float, seed: int, center: str, size: float
) -> tuple["TrajectorySpec", ...]:
    """The trajectories the options describe; a bad value is one line naming its option."""
    from pydantic import ValidationError

    from gainfarm.schemas.trajectory import TrajectorySpec
    from gainfarm.schemas.wire import describe

    point = parse_numbers("--center", center, 3)
    try:
        return tuple(
            TrajectorySpec(kind=kind, duration=duration, seed=seed, center=point, size=size)
            for kind in kinds
        )
    except ValidationError as error:
        field = str(error.errors()[0]["loc"][0]) if error.errors()[0]["loc"] else ""
        option = _FIELD_OPTIONS.get(field, f"--{field}" if field else "--trajectory")
        raise CliError(f"{option}: {describe(error).split(': ', 1)[-1]}") from None


# --- the simulated robot ------------------------------------------------------------------------


def _joint_kinds() -> tuple[str, ...]:
    from gainfarm.schemas.robot import ModelSpec

    return typing.get_args(ModelSpec.model_fields["joints"].annotation)


def _plants() -> tuple[str, ...]:
    from gainfarm.schemas.robot import PLANTS

    return tuple(PLANTS)


def _default_plant() -> str:
    """The plant a run's configuration has by default (RunConfig().model), by name."""
    from gainfarm.schemas.robot import PLANTS, ModelSpec

    return next(name for name, spec in PLANTS.items() if spec == ModelSpec())


def joints(
    help: str | None = "the arm's joints: flexible (a spring between motor and link) or rigid",
) -> Callable[[F], F]:
    """--joints: the joints of the simulated arm, as ModelSpec names them (not --model: that word
    is the learned model's, `analytic learn --kind`)."""
    return click.option(
        "--joints",
        type=LazyChoice(_joint_kinds),
        default=Later(_joint_default),
        show_default=True,
        help=help,
    )


def _joint_default() -> str:
    from gainfarm.schemas.robot import ModelSpec

    return ModelSpec().joints


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
        type=PlantChoice(_plants),
        default=Later(_default_plant),
        show_default=True,
        help=help
        or "realistic: behind KUKA's FRI torque interface (the robot adds gravity "
        "compensation from its own model), with friction, a 1-tick delay, encoders and torque "
        "sensors with noise, motor-side feedback; plain: the same without the robot's gravity "
        "compensation (the paper's plain PD); ideal: the paper's idealised plant; FILE: a plant "
        "file, such as the twin `analytic calibrate` writes",
    )


def model_spec(plant: str, joints: str | None = None, option: str = "--plant") -> "ModelSpec":
    """The ModelSpec of `--plant` (a name or a plant file; `option` names the option that gave
    it), with `--joints` if the command has that option."""
    from gainfarm.schemas.robot import PLANTS

    if plant in PLANTS:
        spec = PLANTS[plant]
        return spec if joints is None else spec.model_copy(update={"joints": joints})
    from gainfarm.models.iiwa14 import check_substeps

    spec = plant_file(plant, option).plant
    spec = spec if joints is None else spec.model_copy(update={"joints": joints})
    try:  # here, not in the middle of a run: a file's springs its physics step cannot hold
        check_substeps(spec)
    except ValueError as error:
        raise CliError(f"{option}: {plant!r}: {error}") from None
    return spec


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


def with_load(
    spec: "ModelSpec",
    payload: float | None,
    payload_com: tuple[float, ...] | None,
    plant: str | None = None,
) -> "ModelSpec":
    """`spec` (--plant `plant`'s) told of the load --payload and --payload-com give (--payload
    0: told of none); without --payload, a plant file's calibrated payload (PlantFile.told),
    else as it is."""
    check_load(payload, payload_com)
    if payload is None:
        if plant is None or plant in _plants():
            return spec
        told = plant_file(plant).told().plant
        return spec.model_copy(update={"payload": told.payload, "load": told.load})
    from gainfarm.schemas.robot import LoadData

    told = LoadData(mass=payload, com=payload_com or (0.0, 0.0, 0.0)) if payload > 0 else None
    return spec.model_copy(update={"load": told})


def plant_file(plant: str, option: str = "--plant") -> "PlantFile":
    """--plant FILE's contents, or one line naming the option and what is wrong."""
    from gainfarm.schemas.documents import BadDocument, read_bounded
    from gainfarm.schemas.plant_file import MAX_FILE_BYTES, BadPlantFile, read_plant_file

    try:
        raw = read_bounded(Path(plant), MAX_FILE_BYTES)
    except OSError as error:
        raise CliError(f"{option}: cannot read {plant!r}: {error.strerror}") from None
    except BadDocument as error:
        raise CliError(f"{option}: {plant!r}: {error}") from None
    try:
        read = read_plant_file(raw)
        plugins.check_name(plugins.ROBOTS, read.plant.robot)  # a twin of an arm not here
    except (BadPlantFile, plugins.PluginError) as error:
        raise CliError(f"{option}: {plant!r}: {error}") from None
    return read


def feedforward(
    help: str = "add a learned inverse-dynamics model's torque for the reference "
    "to the PD (a directory from `analytic learn`, or its model.npz)",
) -> Callable[[F], F]:
    return click.option("--feedforward", type=click.Path(path_type=Path), help=help)


def feedforward_model(path: Path | None) -> tuple[bytes, "DynamicsModel"] | None:
    """--feedforward's model file as bytes (jobs name it by their SHA-256) and decoded; it must
    be an inverse-dynamics model of the seven joints."""
    if path is None:
        return None
    from gainfarm.models.dynamics import (
        MAX_FILE_BYTES,
        MODEL_FILE,
        BadDynamicsModel,
        feedforward_from_bytes,
    )
    from gainfarm.schemas.documents import BadDocument, read_bounded

    file = path / MODEL_FILE if path.is_dir() else path
    try:
        raw = read_bounded(file, MAX_FILE_BYTES)
    except OSError as error:
        raise CliError(f"--feedforward: cannot read {str(file)!r}: {error.strerror}") from None
    except BadDocument as error:
        raise CliError(f"--feedforward: {str(file)!r}: {error}") from None
    try:
        model = feedforward_from_bytes(raw)
    except BadDynamicsModel as error:
        raise CliError(f"--feedforward: {str(file)!r}: {error}") from None
    return raw, model


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


def limits_from(path: Path | None, damping: float | None = None) -> "Limits":
    """--limits FILE's limits (the defaults without one), with --min-damping's bound if given,
    or one line naming the option."""
    from pydantic import ValidationError

    from gainfarm.schemas.wire import describe

    limits = _limits_file(path)
    if damping is None:
        return limits
    try:
        return type(limits).model_validate({**limits.model_dump(), "min_damping": damping})
    except ValidationError as error:
        raise CliError(f"--min-damping: {describe(error)}") from None


def _limits_file(path: Path | None) -> "Limits":
    from pydantic import ValidationError

    from gainfarm.schemas.documents import BadDocument, load_json, read_bounded
    from gainfarm.schemas.limits import Limits
    from gainfarm.schemas.wire import describe

    if path is None:
        return Limits()
    try:
        fields = load_json(read_bounded(path))
    except OSError as error:
        raise CliError(f"--limits: cannot read {str(path)!r}: {error.strerror}") from None
    except BadDocument as error:
        raise CliError(f"--limits: {str(path)!r}: {error}") from None
    except ValueError as error:  # JSONDecodeError, UnicodeDecodeError
        raise CliError(f"--limits: {str(path)!r} is not JSON ({error})") from None
    if not isinstance(fields, dict):
        raise CliError(f"--limits: {str(path)!r} is not a JSON object of limits")
    try:
        return Limits.model_validate(fields)
    except ValidationError as error:
        said = describe(error, known=Limits.model_fields, noun="limit")
        raise CliError(f"--limits: {str(path)!r}: {said}") from None


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


def identity(
    directory: Path | None, role: "Role", name: str | None = None, name_option: str = "--as"
) -> "TlsIdentity | None":
    """The identity in a --tls directory (None without one): participant `name`'s, or without a
    name the directory's only identity of `role`. One line otherwise, naming `name_option` when
    the name is what is wrong (not there, or needed to choose among several) and --tls when a
    file is missing."""
    if directory is None:  # not a secure farm: nothing to load
        return None
    from gainfarm.schemas.security import UnknownIdentity, load_identity

    try:
        return load_identity(directory, role, name)
    except UnknownIdentity as error:
        raise CliError(f"{name_option}: {error}") from None
    except ValueError as error:
        raise CliError(f"--tls: {error}") from None


def log_level() -> Callable[[F], F]:
    return click.option(
        "--log-level", type=click.Choice(LOG_LEVELS), default="info", show_default=True
    )
