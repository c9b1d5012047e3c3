"""Each shipped arm's default references against its data sheet: the peak joint speed and
acceleration of every trajectory kind, as a share of the arm's own limits.

    python bench/references.py [--robots iiwa14,ur5e,...] [--duration S]

For every installed arm (`--robots`) and every built-in kind (spiral, random, pyramid, fourier),
the kind's default spec (TrajectorySpec's defaults, seed 0) placed in the arm's workspace
(centred on its `workspace.center`; the fourier kind moves about its home) at its default
duration on that arm (worker.reference.default_duration: 5 s, or longer where the arm needs it;
`--duration` for another), the reference the worker builds for it (reference_for): per joint,
its largest |q̇| over the speed limit and |q̈| over the acceleration limit; the table gives the
largest of each over the joints, which joint it is, the duration, and the kind's shortest
feasible duration on that arm. Issue 49's target: every share at most 0.9 (the fourier kind
scales itself to 0.85; a Cartesian kind's shares are at most its shortest feasible duration over
the duration, to the first and second power, since the worker times its segments by their
shortest times).
"""

import time

import click
import numpy as np
from common import print_table

from gainfarm import plugins
from gainfarm.models import robot_of
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec
from gainfarm.worker.reference import (
    DEFAULT_SHARE,
    arm_of,
    default_duration,
    reference_for,
    shortest_duration,
)


def default_spec(robot: str, kind: str, duration: float | None) -> TrajectorySpec:
    """The kind's default spec on the arm: centred on its workspace centre, its default duration
    there (or `duration`)."""
    spec = TrajectorySpec(kind=kind, center=robot_of(robot).workspace.center)
    chosen = default_duration(spec, robot) if duration is None else duration
    return spec.model_copy(update={"duration": chosen})


def peaks(robot: str, spec: TrajectorySpec) -> tuple[float, str, float, str]:
    """(largest speed share, its joint, largest acceleration share, its joint)."""
    arm = arm_of(robot)
    reference = reference_for(spec, robot)
    speed = np.abs(reference.qd).max(axis=0) / arm.speed
    acceleration = np.abs(reference.qdd).max(axis=0) / arm.acceleration
    fast, hard = int(speed.argmax()), int(acceleration.argmax())
    return float(speed[fast]), arm.joint(fast), float(acceleration[hard]), arm.joint(hard)


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--robots", help="comma-separated arms  [default: every installed one]")
@click.option(
    "--duration",
    type=click.FloatRange(min=0.1, max=120),
    help="s, every kind's  [default: each kind's default duration on each arm]",
)
def main(robots: str | None, duration: float | None) -> None:
    names = plugins.names(plugins.ROBOTS) if robots is None else tuple(robots.split(","))
    rows, worst = [], 0.0
    began = time.perf_counter()
    for robot in names:
        try:
            robot_of(robot)
        except plugins.PluginError as error:
            raise click.BadParameter(str(error), param_hint="'--robots'") from None
        for kind in TrajectoryKind:
            spec = default_spec(robot, kind.value, duration)
            speed, fast, acceleration, hard = peaks(robot, spec)
            worst = max(worst, speed, acceleration)
            rows.append(
                (
                    robot,
                    kind.value,
                    f"{spec.duration:g}",
                    f"{speed:.2f} ({fast})",
                    f"{acceleration:.2f} ({hard})",
                    f"{shortest_duration(spec, robot):.1f}",
                )
            )
    print(
        "default references (seed 0, each arm's workspace centre): peak share of the data "
        "sheet's limit, over the joints (the joint)\n"
    )
    print_table(
        ("arm", "kind", "duration s", "speed / limit", "acceleration / limit", "shortest s"),
        "llrrrr",
        rows,
    )
    took = time.perf_counter() - began
    print(f"\nlargest share: {worst:.2f} (target <= {DEFAULT_SHARE:g}); {took:.0f} s")


if __name__ == "__main__":
    main()
