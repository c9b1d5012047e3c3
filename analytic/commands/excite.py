"""`analytic excite`: safe excitation references to record on a real arm, for `calibrate`."""

import math
from pathlib import Path

import click

from gainfarm.analytic.commands.shared import uncertainty
from gainfarm.cli.app import CliError

# Light: the defaults and bounds click checks before anything heavy loads.
DURATION = 10.0  # s: every joint moves 0.19 rad at least (seeds 0-99; 0.20 at 3 s)
COUNT = 10
MAX_COUNT = 100  # two digits in the files' names
SHIPPED_RANGES = "the shipped models/uncertainty.toml"


@click.command()
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    required=True,
    metavar="DIR",
    help="directory to write (new, or empty): the references, controller.json, README.md",
)
@click.option(
    "--duration",
    type=float,
    default=DURATION,
    metavar="S",
    show_default=True,
    help="seconds per excitation (0.1 to 120)",
)
@click.option(
    "--count",
    type=click.IntRange(1, MAX_COUNT),
    default=COUNT,
    metavar="N",
    show_default=True,
    help="excitations to write",
)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    metavar="K",
    show_default=True,
    help="excitation NN is the fourier trajectory of seed K + NN",
)
@uncertainty(
    "the plant ranges the gains must be stable on, a TOML file in the form of the shipped "
    "models/uncertainty.toml  [default: that file]"
)
def excite(
    out: Path, duration: float, count: int, seed: int, uncertainty_file: Path | None
) -> None:
    """Write safe excitation references to record on a real arm, for `analytic calibrate`.

    Each is a fourier trajectory (every joint moves, rest to rest) at 500 Hz as JSON and as a
    ROS 2 JointTrajectory in MCAP, with the PD gains to play it with and a README saying what to
    record. Refused, with nothing written, unless every reference stays within the iiwa 14's
    published limits and moves every joint, and the gains are stable on the nominal plant and on
    plants drawn from the uncertainty ranges.
    """
    import os
    import shutil

    from pydantic import ValidationError

    from gainfarm.analytic.calibration import excitation as ex
    from gainfarm.analytic.commands.shared import plants_from
    from gainfarm.edges.files import staging_directory, write_atomically
    from gainfarm.schemas.robot import ModelSpec
    from gainfarm.schemas.trajectory import MAX_DURATION, MIN_DURATION

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
    ranges = SHIPPED_RANGES if uncertainty_file is None else repr(str(uncertainty_file))

    command = f"analytic excite --duration {duration:g} --count {count} --seed {seed}"
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
            variants = plants_from(ex.VARIANTS, uncertainty_file, ModelSpec(), trajectory.seed)
            try:
                item = ex.excitation(index, trajectory, variants, ranges)
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
            ("controller.json", ex.gains_json()),
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
        f"{out}: within the iiwa 14's limits, every joint moving {ex.MIN_SPAN:g} rad at least; "
        f"the gains stable on {worst.plants} plants each (the nominal and {ex.VARIANTS} drawn from "
        f"{ranges}): least damping {worst.damping:+.3f} ({worst.name})"
    )
