"""`analytic excite` once it runs: what its function in analytic/commands/excite.py does."""

import math
import os
import shutil
from pathlib import Path

import click
from pydantic import ValidationError

from gainfarm.analytic.calibration import excitation as ex
from gainfarm.analytic.commands.work.common import plants_from
from gainfarm.cli.app import CliError
from gainfarm.edges.files import staging_directory, write_atomically
from gainfarm.schemas.robot import DEFAULT_ROBOT
from gainfarm.schemas.trajectory import MAX_DURATION, MIN_DURATION

SHIPPED_RANGES = "the shipped models/uncertainty.toml"


def excite(
    out: Path,
    duration: float,
    count: int,
    seed: int,
    uncertainty_file: Path | None,
    robot: str = DEFAULT_ROBOT,
) -> None:
    """`analytic excite` with its options as parsed (analytic/commands/excite.py)."""
    # The options first, cheapest first: nothing is computed for a command that will be refused.
    if not (math.isfinite(duration) and MIN_DURATION <= duration <= MAX_DURATION):
        raise CliError(
            f"--duration: {duration:g} s is outside {MIN_DURATION:g} to {MAX_DURATION:g} s"
        )
    if seed + count > 2**63:  # TrajectorySpec's bound on a seed
        raise CliError(f"--seed: {seed} + {count} excitations passes the largest seed, 2**63 - 1")
    if out.exists() and not (out.is_dir() and not any(out.iterdir())):
        raise CliError(f"--out: {str(out)!r} already exists and is not an empty directory")
    if not out.parent.is_dir():
        raise CliError(f"--out: directory {str(out.parent)!r} does not exist")
    shipped = SHIPPED_RANGES if robot == DEFAULT_ROBOT else f"{robot}'s shipped ranges"
    ranges = shipped if uncertainty_file is None else repr(str(uncertainty_file))

    command = f"analytic excite --duration {duration:g} --count {count} --seed {seed}"
    if robot != DEFAULT_ROBOT:
        command += f" --robot {robot}"
    if uncertainty_file is not None:
        command += f" --uncertainty {uncertainty_file}"

    # Built beside --out and renamed into place once every excitation has passed every check:
    # a refusal leaves nothing, and --out appears whole (a rename onto an empty directory
    # replaces it). Each excitation's files are written as it passes, so that memory holds one
    # excitation's bytes at a time (3 MB per 10 s), not all of them.
    excitations = []
    written = 0
    staging = None
    try:
        staging = staging_directory(out)
        for index in range(count):
            try:
                trajectory = ex.trajectory(duration, seed + index)
            except ValidationError as error:  # the bounds are checked above: their backstop
                raise CliError(f"--duration: {error.errors()[0]['msg']}") from None
            # Each excitation meets plants of its own (its seed's): more of the ranges covered.
            nominal = ex.nominal(robot)
            variants = plants_from(ex.VARIANTS, uncertainty_file, nominal, trajectory.seed)
            try:
                item = ex.excitation(index, trajectory, variants, ranges, robot=robot)
            except ex.Unsafe as error:
                raise CliError(f"{error.option}: {error}") from None
            for file_name, content in (
                (f"{item.name}.json", ex.document_json(item)),
                (f"{item.name}.mcap", ex.trajectory_mcap(item)),
            ):
                write_atomically(staging / file_name, content)
                written += len(content)
            excitations.append(item)
        for file_name, content in (
            ("controller.json", ex.gains_json(ex.gains_for(robot))),
            ("README.md", ex.readme(excitations, command, ranges).encode()),
        ):
            write_atomically(staging / file_name, content)
            written += len(content)
        os.replace(staging, out)
    except BaseException as error:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        if isinstance(error, OSError):
            raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror}") from None
        raise
    worst = min(excitations, key=lambda item: item.damping)
    megabytes = written / 1e6
    click.echo(
        f"{out}: {count} excitations of {duration:g} s (seeds {seed} to {seed + count - 1}), "
        f"excitation-NN.json and .mcap, controller.json, README.md ({megabytes:.1f} MB)"
    )
    click.echo(
        f"{out}: within {robot}'s limits, every joint moving {ex.MIN_SPAN:g} rad at least; "
        f"the gains stable on {worst.plants} plants each (the nominal and {ex.VARIANTS} drawn from "
        f"{ranges}): least damping {worst.damping:+.3f} ({worst.name})"
    )
