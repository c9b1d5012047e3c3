"""The options several commands share, each written once: same name, type, default and help.

A decorator per option (or group of options that always go together); the choices come from the
contract (schemas/), so a new trajectory kind or model variant reaches every command by itself.
"""

import typing
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import click
from pydantic import ValidationError

from gainfarm.cli.app import CliError, parse_numbers
from gainfarm.models.dynamics import (
    MODEL_FILE,
    BadDynamicsModel,
    DynamicsModel,
    feedforward_from_bytes,
)
from gainfarm.schemas.robot import PLANTS, ModelSpec
from gainfarm.schemas.security import Role, TlsIdentity, UnknownIdentity, load_identity
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec
from gainfarm.schemas.wire import describe

F = TypeVar("F", bound=Callable[..., object])

TRAJECTORY_KINDS = [kind.value for kind in TrajectoryKind]
MODEL_JOINTS = list(typing.get_args(ModelSpec.model_fields["joints"].annotation))
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
LOG_LEVELS = ("debug", "info", "warning", "error")


def stack(*options: Callable[[F], F]) -> Callable[[F], F]:
    """Apply `options` so that they appear in --help in the order given."""

    def decorate(command: F) -> F:
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


def trajectory(multiple: bool = False, help: str = "end-effector path") -> Callable[[F], F]:
    """--trajectory: one kind (parameter `trajectory`), or several (parameter `kinds`)."""
    if multiple:
        return click.option(
            "--trajectory",
            "kinds",
            multiple=True,
            type=click.Choice(TRAJECTORY_KINDS),
            default=[TrajectoryKind.spiral.value],
            show_default=True,
            help=help,
        )
    return click.option(
        "--trajectory",
        type=click.Choice(TRAJECTORY_KINDS),
        default=TrajectoryKind.spiral.value,
        show_default=True,
        help=help,
    )


def duration(help: str = "seconds") -> Callable[[F], F]:
    """--duration of the trajectory; its range is checked where the TrajectorySpec is made."""
    return click.option("--duration", type=float, default=5.0, show_default=True, help=help)


def model(help: str | None = "elastic or rigid joints") -> Callable[[F], F]:
    """--model: the joints of the simulated robot, as ModelSpec names them."""
    return click.option(
        "--model",
        type=click.Choice(MODEL_JOINTS),
        default=ModelSpec().joints,
        show_default=True,
        help=help,
    )


def plant() -> Callable[[F], F]:
    """--plant: the realistic plant (the default) or the first wave's idealised one."""
    return click.option(
        "--plant",
        type=click.Choice(list(PLANTS)),
        default="realistic",
        show_default=True,
        help="realistic: friction, a 1-tick delay, encoders and torque sensors with noise, "
        "motor-side feedback, KUKA's CAD masses; ideal: the paper's idealised plant",
    )


def model_spec(plant: str, joints: str) -> ModelSpec:
    """The ModelSpec of `--plant` with `--model`'s joints."""
    return PLANTS[plant].model_copy(update={"joints": joints})


_TRAJECTORY = TrajectorySpec()


def placement() -> Callable[[F], F]:
    """--trajectory-seed, --center and --size: where a trajectory lies and which one it is, so
    that datasets can cover the workspace."""
    return stack(
        click.option(
            "--trajectory-seed",
            type=click.IntRange(min=0),
            default=_TRAJECTORY.seed,
            show_default=True,
            help="seed of the random kind's waypoints and the fourier kind's coefficients",
        ),
        click.option(
            "--center",
            default=",".join(f"{v:g}" for v in _TRAJECTORY.center),
            show_default=True,
            help="x,y,z of the path's centre in the base frame, m (not fourier)",
        ),
        click.option(
            "--size",
            type=float,
            default=_TRAJECTORY.size,
            show_default=True,
            help="the path's half-width, m (not fourier)",
        ),
    )


_FIELD_OPTIONS = {"seed": "--trajectory-seed", "center": "--center", "size": "--size"}


def trajectories(
    kinds: typing.Iterable[str], duration: float, seed: int, center: str, size: float
) -> tuple[TrajectorySpec, ...]:
    """The trajectories the options describe; a bad value is one line naming its option."""
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


def connect(help: str) -> Callable[[F], F]:
    """--connect ENDPOINT (repeatable), the farm's broker on this host by default."""
    return click.option(
        "--connect", multiple=True, default=[DEFAULT_CONNECT], show_default=True, help=help
    )


def tls(help: str) -> Callable[[F], F]:
    """--tls DIR: the credentials of a secure farm (load them with `identity`)."""
    return click.option("--tls", type=click.Path(path_type=Path), help=help)


def participant(role: Role) -> Callable[[F], F]:
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
    directory: Path | None, role: Role, name: str | None = None, name_option: str = "--as"
) -> TlsIdentity | None:
    """The identity in a --tls directory (None without one): participant `name`'s, or without a
    name the directory's only identity of `role`. One line otherwise, naming `name_option` when
    the name is what is wrong (not there, or needed to choose among several) and --tls when a
    file is missing."""
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


def feedforward(
    help: str = "add a learned inverse-dynamics model's torque for the reference "
    "to the PD (a directory from `analytic learn`, or its model.npz)",
) -> Callable[[F], F]:
    return click.option("--feedforward", type=click.Path(path_type=Path), help=help)


def feedforward_model(path: Path | None) -> tuple[bytes, DynamicsModel] | None:
    """--feedforward's model file as bytes (jobs name it by their SHA-256) and decoded; it must
    be an inverse-dynamics model of the seven joints."""
    if path is None:
        return None
    file = path / MODEL_FILE if path.is_dir() else path
    try:
        raw = file.read_bytes()
    except OSError as error:
        raise CliError(f"--feedforward: cannot read {str(file)!r}: {error.strerror}") from None
    try:
        model = feedforward_from_bytes(raw)
    except BadDynamicsModel as error:
        raise CliError(f"--feedforward: {str(file)!r}: {error}") from None
    return raw, model
