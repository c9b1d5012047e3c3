"""What `worker episode` and `analytic batch` say of the gains they are given, said once: gains
that would saturate every tick are refused, gains far outside the search space are warned of."""

from collections.abc import Sequence
from pathlib import Path

import click

from gainfarm.cli.app import CliError
from gainfarm.schemas.gains import PDGains, outside_search, saturating
from gainfarm.schemas.robot import PlantSpec, Robot


def refuse_saturating(
    candidates: Sequence[PDGains],
    plant: PlantSpec,
    path: Path | None = None,
    robot: Robot | None = None,
) -> None:
    """One line for the first candidate with a gain that saturates its motor on one encoder
    count of `model`: every tick of its episodes would saturate. It names --gains and the file
    (and the candidate, if the file holds several), or the option --kp or --kd without a file.
    `robot`: the plant's (its joints and torque limits; None: the iiwa 14)."""
    arm = () if robot is None else (robot.joint_names, robot.limits.torque)
    for number, gains in enumerate(candidates, start=1):
        found = saturating(gains, plant, *arm)
        if found is None:
            continue
        which, joint, gain = found
        given = f"--gains: {str(path)!r}: " if path is not None else f"--{which}: "
        candidate = f"candidate {number}: " if len(candidates) > 1 else ""
        raise CliError(
            f"{given}{candidate}{which} of {joint} is {gain:g}, which saturates its motor on one "
            "encoder count: every tick would saturate"
        )


def warn_far_outside_search(
    program: str,
    candidates: Sequence[PDGains],
    path: Path | None = None,
    robot: Robot | None = None,
) -> None:
    """One line on stderr for the first candidate with gains orders of magnitude outside what
    the farm searches: its episodes run (a user may mean them), but such gains are more often a
    slip of units or of an exponent. It names --gains and the file (and the candidate, if the
    file holds several), or the option --kp or --kd without a file. `robot`: whose default gains
    the search space is built on (None: the iiwa 14's)."""
    arm = () if robot is None else (robot.default_gains, robot.joint_names)
    for number, gains in enumerate(candidates, start=1):
        found = outside_search(gains, *arm)
        if found is None:
            continue
        # The phrase starts with the gain's name, kp or kd: the option that gave it.
        given = f"--gains {str(path)!r}" if path is not None else f"--{found[:2]}"
        candidate = f"candidate {number}: " if len(candidates) > 1 else ""
        click.echo(
            f"{program}: warning: {given}: {candidate}{found}: far outside what the farm "
            "searches (a slip of units or of an exponent?)",
            err=True,
        )
        return
