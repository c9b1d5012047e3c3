"""What the options several commands share (options.py) say, made into the contract's objects:
the trajectories, the plant, its told load, the safety limits, the feed-forward model, a secure
farm's identity. Each bad value is one line naming its option (CliError).

Apart from options.py, which a command's module imports to declare its options: this module
loads pydantic and the contract, so a command imports it when it runs, not to parse or show
--help. MuJoCo loads only for what needs it (a plant file's physics step, a learned model).
"""

import typing
from pathlib import Path
from typing import TYPE_CHECKING

from pydantic import ValidationError

from gainfarm import plugins
from gainfarm.cli.app import CliError, parse_numbers
from gainfarm.cli.options import check_load
from gainfarm.schemas.documents import BadDocument, load_json, read_bounded
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.plant_file import MAX_FILE_BYTES, BadPlantFile, PlantFile, read_plant_file
from gainfarm.schemas.robot import PLANTS, LoadData, PlantSpec
from gainfarm.schemas.security import Role, TlsIdentity, UnknownIdentity, load_identity
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.wire import describe

if TYPE_CHECKING:
    from gainfarm.models.dynamics import DynamicsModel

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


def model_spec(plant: str, joints: str | None = None, option: str = "--plant") -> "PlantSpec":
    """The PlantSpec of `--plant` (a name or a plant file; `option` names the option that gave
    it), with `--joints` if the command has that option."""
    if plant in PLANTS:
        spec = PLANTS[plant]
        return spec if joints is None else spec.model_copy(update={"joints": joints})
    spec = plant_file(plant, option).plant
    # start-up: MuJoCo (models) loads only for a readable plant file, whose springs it checks
    from gainfarm.models import compile_model

    spec = spec if joints is None else spec.model_copy(update={"joints": joints})
    try:  # here, not in the middle of a run: a file's springs its physics step cannot hold
        compile_model(spec)  # the named robot's build refuses them (any arm's, not the iiwa's)
    except ValueError as error:
        raise CliError(f"{option}: {plant!r}: {error}") from None
    return spec


def with_load(
    spec: "PlantSpec",
    payload: float | None,
    payload_com: tuple[float, ...] | None,
    plant: str | None = None,
) -> "PlantSpec":
    """`spec` (--plant `plant`'s) told of the load --payload and --payload-com give (--payload
    0: told of none); without --payload, a plant file's calibrated payload (PlantFile.told),
    else as it is."""
    check_load(payload, payload_com)
    if payload is None:
        if plant is None or plant in PLANTS:
            return spec
        told = plant_file(plant).told().plant
        return spec.model_copy(update={"payload": told.payload, "load": told.load})
    told = LoadData(mass=payload, com=payload_com or (0.0, 0.0, 0.0)) if payload > 0 else None
    return spec.model_copy(update={"load": told})


def plant_file(plant: str, option: str = "--plant") -> "PlantFile":
    """--plant FILE's contents, or one line naming the option and what is wrong."""
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


def feedforward_model(
    path: Path | None, robot: str | None = None
) -> tuple[bytes, "DynamicsModel"] | None:
    """--feedforward's model file as bytes (jobs name it by their SHA-256) and decoded; it must
    be an inverse-dynamics model, of the arm `robot` names if given."""
    if path is None:
        return None
    # start-up: MuJoCo (models.dynamics) loads only for --feedforward
    from gainfarm.models import dynamics

    file = path / dynamics.MODEL_FILE if path.is_dir() else path
    try:
        raw = read_bounded(file, dynamics.MAX_FILE_BYTES)
    except OSError as error:
        raise CliError(f"--feedforward: cannot read {str(file)!r}: {error.strerror}") from None
    except BadDocument as error:
        raise CliError(f"--feedforward: {str(file)!r}: {error}") from None
    try:
        model = dynamics.feedforward_from_bytes(raw, robot)
    except dynamics.BadDynamicsModel as error:
        raise CliError(f"--feedforward: {str(file)!r}: {error}") from None
    return raw, model


def limits_from(path: Path | None, damping: float | None = None) -> "Limits":
    """--limits FILE's limits (the defaults without one), with --min-damping's bound if given,
    or one line naming the option."""
    limits = _limits_file(path)
    if damping is None:
        return limits
    try:
        return type(limits).model_validate({**limits.model_dump(), "min_damping": damping})
    except ValidationError as error:
        raise CliError(f"--min-damping: {describe(error)}") from None


def _limits_file(path: Path | None) -> "Limits":
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


def identity(
    directory: Path | None, role: "Role", name: str | None = None, name_option: str = "--as"
) -> "TlsIdentity | None":
    """The identity in a --tls directory (None without one): participant `name`'s, or without a
    name the directory's only identity of `role`. One line otherwise, naming `name_option` when
    the name is what is wrong (not there, or needed to choose among several) and --tls when a
    file is missing."""
    if directory is None:  # not a secure farm: nothing to load
        return None
    try:
        return load_identity(directory, role, name)
    except UnknownIdentity as error:
        raise CliError(f"{name_option}: {error}") from None
    except ValueError as error:
        raise CliError(f"--tls: {error}") from None
