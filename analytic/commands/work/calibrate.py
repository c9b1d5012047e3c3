"""`analytic calibrate` once it runs: what its function in analytic/commands/calibrate.py does."""

import json
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.console import Console
from rich.table import Table

from gainfarm.analytic.calibration.identify import identify
from gainfarm.analytic.calibration.logs import BadLog, Topics, read_recording
from gainfarm.analytic.calibration.twin import OtherArm, for_robot, twin_file, write_text
from gainfarm.analytic.tuning.plants import BadUncertainty, ranges_of
from gainfarm.cli import values
from gainfarm.cli.app import CliError
from gainfarm.edges.files import write_atomically
from gainfarm.models import plant_preset, robot_of
from gainfarm.schemas.robot import DEFAULT_ROBOT, PLANTS, PlantSpec

if TYPE_CHECKING:
    from gainfarm.analytic.tuning.plants import Range


def calibrate(
    logs: tuple[Path, ...],
    out: Path,
    plant: str,
    payload: float | None,
    payload_com: tuple[float, ...] | None,
    seed: int,
    joint_states: str,
    commands: str,
    motor_states: str,
    as_json: bool,
    robot: str | None = DEFAULT_ROBOT,
) -> None:
    """`analytic calibrate` with its options as parsed (analytic/commands/calibrate.py); `robot`
    None: --robot not given (a plant file's arm, else the iiwa 14)."""
    # The arm as it recorded: a twin's own payload stays untold (no `plant` given), as it was.
    nominal = values.with_load(_nominal(plant, robot), payload, payload_com)
    prior = _prior_ranges(plant)
    if not out.parent.is_dir():
        raise CliError(f"--out: directory {str(out.parent)!r} does not exist")
    topics = Topics(joint_states, commands, motor_states)
    recordings = []
    for path in logs:
        try:
            recordings.append(read_recording(path, topics, nominal.robot))
        except BadLog as error:
            raise CliError(str(error)) from None
    if nominal.joints != "flexible":
        raise CliError("--plant: calibration fits elastic joints; this plant's are rigid")
    try:
        fit = identify(recordings, nominal, seed)
        twin = twin_file(fit, nominal, logs, prior)
    except ValueError as error:
        raise CliError(str(error)) from None
    try:
        write_atomically(out, write_text(twin).encode())
    except OSError as error:
        raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror}") from None
    if as_json:
        click.echo(json.dumps({"twin": str(out), **twin.calibration}))
        return
    _show(twin.calibration, out, robot_of(nominal).joint_names)


def _nominal(plant: str, robot: str | None) -> PlantSpec:
    """--plant's plant on --robot: a preset of the arm, or a plant file (a twin) of it, one of
    another arm refused; without --robot, a plant file's own arm (a preset's: the iiwa 14)."""
    if plant in PLANTS:
        return plant_preset(plant, robot or DEFAULT_ROBOT)
    spec = values.model_spec(plant)
    try:
        return spec if robot is None else for_robot(spec, robot)
    except OtherArm as error:
        raise CliError(str(error)) from None


def _prior_ranges(plant: str) -> "dict[str, Range] | None":
    """--plant's own uncertainty, if it is a plant file that has one (a twin calibrated again)."""
    if plant in PLANTS:
        return None
    try:
        return ranges_of(values.plant_file(plant).uncertainty) or None
    except BadUncertainty as error:
        raise CliError(f"--plant: {plant!r}: uncertainty: {error}") from None


def _show(calibration: dict, out: Path, joints: tuple[str, ...]) -> None:
    """The fit per joint, each number with its spread, the untold ones marked."""
    columns = (
        ("rotor_inertia", "B kg·m²"),
        ("stiffness", "K N·m/rad"),
        ("spring_damping", "D N·m·s/rad"),
        ("coulomb", "F_c N·m"),
        ("viscous", "F_v N·m·s/rad"),
        ("mass_scale", "mass scale"),
    )
    table = Table(
        "joint",
        *(label for _, label in columns),
        title=f"{out}: fitted on {calibration['episodes']} episodes (± one bootstrap deviation; "
        "dim: not told by the logs)",
    )
    for joint, name in enumerate(joints):
        cells = []
        for key, _ in columns:
            entry = calibration[key]
            fit, spread = entry["fit"][joint], entry["spread"][joint]
            if entry["told"][joint]:
                cells.append(f"{fit:.4g} ±{spread / abs(fit):.1%}")
            else:
                cells.append(f"[dim]{fit:.4g}[/dim]")
        table.add_row(name, *cells)
    console = Console(stderr=False)
    console.print(table)
    delay, smoothing = calibration["delay"], calibration["smoothing"]
    payload = calibration["payload"]
    told = f"±{smoothing['spread']:.1%}" if smoothing["told"] else "untold, the nominal kept"
    console.print(
        f"delay {delay['ticks']} ticks ({delay['support']:.0%} of bootstrap resamples); "
        f"friction smoothing {smoothing['fit']:.3g} rad/s ({told}); "
        f"payload {payload['fit'][0]:.3g} kg"
    )
    seen = set()
    for name, _ in (*columns, ("payload", "")):
        why = calibration[name]["why"]
        if why and why not in seen:
            seen.add(why)
            console.print(f"untold, {name}: {why}")
    for note in calibration["notes"]:
        console.print(f"note: {note}")
