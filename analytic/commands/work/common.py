"""What the `analytic` commands that take a run's or a farm's options make of them: the plant
variants, the farm's identity, a RunConfig's complaint naming its option. Loaded when a command
runs (pydantic and the contract), before anything heavier: a bad option is refused before
MuJoCo, Zenoh, pymoo or matplotlib load."""

from collections.abc import Callable
from pathlib import Path

import click
from pydantic import ValidationError

from gainfarm.analytic.commands.shared import farm_rules
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.cli import values
from gainfarm.cli.app import CliError
from gainfarm.schemas.documents import BadDocument, read_bounded
from gainfarm.schemas.plant_file import PlantFile
from gainfarm.schemas.robot import DEFAULT_ROBOT, PLANTS, PlantSpec
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.wire import describe, one_line


def robot_plant(plant: str, joints: str | None, robot: str) -> PlantSpec:
    """--plant's PlantSpec on --robot's arm: a preset (realistic, plain, ideal) of `robot`, or a
    plant file's (a calibrated twin names its own robot); with --joints if given. One line
    naming the option if --robot names another arm than the twin's."""
    if plant not in PLANTS:
        spec = values.model_spec(plant, joints)
        if robot != DEFAULT_ROBOT and spec.robot != robot:
            raise CliError(
                f"--robot: {robot}, but --plant {plant!r} is a twin of {spec.robot} (a twin of "
                "one arm is no plant of another)"
            )
        return spec
    # start-up: the robot's module (MuJoCo) loads once the cheaper options are checked
    from gainfarm.models import plant_preset

    spec = plant_preset(plant, robot)
    return spec if joints is None else spec.model_copy(update={"joints": joints})


def centre(center: str | None, robot: str) -> str:
    """--center as given, or else (None) the centre of the robot's workspace, where its default
    trajectories lie (--center's form: x,y,z in m)."""
    if center is not None:
        return center
    # start-up: the robot's module (MuJoCo) loads once the cheaper options are checked
    from gainfarm.models import robot_of

    return ",".join(repr(float(v)) for v in robot_of(robot).workspace.center)


def on_the_robot(
    trajectories: "tuple[TrajectorySpec, ...]", duration: float | None, robot: str
) -> "tuple[TrajectorySpec, ...]":
    """The trajectories with --duration as given, or else (None) each kind's default duration
    on the robot (worker.reference.default_duration: 5 s, or longer on an arm too slow for it
    within its limits' share)."""
    if duration is not None:
        return trajectories
    # start-up: the references (SciPy, MuJoCo) load once the cheaper options are checked
    from gainfarm.worker.reference import default_duration

    return tuple(_on_the_robot(t, robot, default_duration) for t in trajectories)


def _on_the_robot(
    trajectory: "TrajectorySpec", robot: str, default_duration: Callable
) -> "TrajectorySpec":
    try:
        duration = default_duration(trajectory, robot)
    except ValueError:  # a path out of reach: as given, for the reach check to refuse in one line
        return trajectory
    return trajectory.model_copy(update={"duration": duration})


def _uncertainty(plant_file: PlantFile, nominal: PlantSpec) -> dict:
    """The plant file's ranges for `nominal`: once its calibrated payload is the told load (no
    --payload given: values.with_load), that load's error instead of the untold payload's."""
    told = plant_file.told()
    if (nominal.load, nominal.payload) == (told.plant.load, told.plant.payload):
        return told.uncertainty
    return plant_file.uncertainty


def plants_from(
    count: int,
    path: Path | None,
    nominal: PlantSpec,
    seed: int,
    held_out: bool = False,
    plant: str | None = None,
    designed: bool = False,
    holds: "Callable[[PlantSpec], bool] | None" = None,
) -> tuple[PlantSpec, ...]:
    """--plants K variants of `nominal` (`held_out`: --check-plants M of them, on the seed's
    other stream; `designed`: robust tuning's, the corners first, each where the default gains
    still hold if `holds` says so: plants.held_design), drawn from --uncertainty FILE's ranges,
    else from those of the plant file --plant names (a calibrated twin's), else the robot's own;
    or one line naming the option."""
    # start-up: MuJoCo (a variant's physics step) loads once the cheaper options are checked
    from gainfarm.analytic.tuning.plants import (
        CORNERS,
        HELD_OUT,
        TUNING,
        BadUncertainty,
        design,
        held_design,
        ranges,
        ranges_of,
        variants,
    )

    stream = HELD_OUT if held_out else TUNING

    def drawn(table: "dict | None") -> tuple[PlantSpec, ...]:
        if designed and holds is not None:
            found, shares = held_design(nominal, count, seed, holds, table)
            for name, share in zip(CORNERS, shares, strict=False):
                if share < 1:  # said: the run's plants are not the ranges' ends
                    click.echo(
                        f"--plants: the {name} corner {share:g} of the way to the ranges' ends, "
                        f"where {nominal.robot}'s default gains keep to the limits",
                        err=True,
                    )
            return found
        if designed:
            return design(nominal, count, seed, table)
        return variants(nominal, count, seed, table, stream)

    if path is None:
        table = None
        if plant is not None and plant not in PLANTS:
            try:
                table = ranges_of(_uncertainty(values.plant_file(plant), nominal)) or None
            except BadUncertainty as error:
                raise CliError(f"--plant: {plant!r}: uncertainty: {error}") from None
        try:
            return drawn(table)
        except ValueError as error:
            raise CliError(
                f"--plant: {plant!r}: a variant is no plant ({one_line(error)})"
            ) from None
    try:
        text = read_bounded(path).decode()
    except OSError as error:
        raise CliError(f"--uncertainty: cannot read {str(path)!r}: {error.strerror}") from None
    except BadDocument as error:
        raise CliError(f"--uncertainty: {str(path)!r}: {error}") from None
    except UnicodeDecodeError:
        raise CliError(f"--uncertainty: {str(path)!r} is not text") from None
    try:
        table = ranges(text)
    except BadUncertainty as error:
        raise CliError(f"--uncertainty: {str(path)!r}: {error}") from None
    if not table:
        # An empty file (or one with no table) would draw every variant equal to the nominal
        # plant: robust tuning that is not, without a word.
        raise CliError(
            f"--uncertainty: {str(path)!r} holds no ranges (a table per parameter, as in the "
            "shipped models/uncertainty.toml)"
        )
    try:
        return drawn(table)
    except ValueError as error:  # a range that takes the plant out of what it may be
        raise CliError(
            f"--uncertainty: {str(path)!r}: a variant is no plant ({one_line(error)})"
        ) from None


def check_farm(
    connect: tuple[str, ...], local: bool, tls: Path | None, participant: str | None
) -> TlsIdentity | None:
    """The analytic identity to connect with, if the farm is secure."""
    farm_rules({"connect": connect, "local": local, "tls": tls, "participant": participant})
    return values.identity(tls, "analytic", participant)


def config_problem(error: ValidationError) -> str:
    """A RunConfig's complaint in one line, naming the option when it is one field's."""
    text = describe(error)
    field, _, rest = text.partition(": ")
    if rest and field in ("algorithm", "objective_scaling", "pop", "seed", "keep"):
        return f"--{field.replace('_', '-')}: {rest}"
    return text.replace("generations and evaluations", "--generations and --evaluations")


def make_config(fields: dict) -> RunConfig:
    """The RunConfig of `fields` (a command's options), or one line naming the option."""
    try:
        return RunConfig(**fields)
    except ValidationError as error:
        raise CliError(config_problem(error)) from None
