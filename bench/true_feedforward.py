"""The floor a feed-forward can reach: the default gains on held-out paths with PD alone, the
nominal rigid arm's feed-forward, the plant's own model (the anchor), and that model with the
command's delay and the springs' deflection compensated. docs/experiments.md quotes the table.

    python bench/true_feedforward.py [--plant realistic|plain|ideal] [--robot iiwa14]
        [--paths 6] [--duration 3]

Held-out paths: fourier excitations and random paths of seeds 4242.., and spirals whose centre
moves 5-10 cm from the training paths' (a seed no run or test uses, alternately; on another arm
than the iiwa 14, its workspace centre moved so, within its box), on the robot's default gains.
Each condition's episode is simulated in this process (worker.episode.simulate, the worker's own
loop); its mean Cartesian error f_acc is printed in mm per path, then the mean and the largest
over the paths. Last, what a model costs the worker: µs per reference row of the rigid prior's
and the true model's inverse dynamics (2,500 random rows, a 5 s reference at 500 Hz; best of 3).
"""

import statistics
import time
from collections.abc import Callable

import click
import numpy as np

from gainfarm.analytic.experiments.feedforward import held_out_paths
from gainfarm.models import plant_preset, resolve, robot_of
from gainfarm.models.dynamics import rigid_prior, true_model
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import DEFAULT_ROBOT, PLANTS
from gainfarm.worker.episode import compensation, simulate, true_compensation
from gainfarm.worker.reference import Reference, reference_for
from gainfarm.worker.trajectories import label

FIRST_SEED = 4242
CENTRES = ((0.5, 0.1, 0.4), (0.6, -0.1, 0.3))  # moved from the default (0.55, 0, 0.35) m
MOVES = ((-0.05, 0.1, 0.05), (0.05, -0.1, -0.05))  # the same moves, from another arm's centre


def centres(robot: str) -> tuple[tuple[float, float, float], ...]:
    """The moved spirals' centres: CENTRES on the iiwa 14, else its workspace centre moved by
    MOVES, each kept within its workspace box."""
    if robot == DEFAULT_ROBOT:
        return CENTRES
    box = robot_of(robot).workspace
    moved = np.clip(np.add(box.center, MOVES), box.low, box.high)
    return tuple((float(x), float(y), float(z)) for x, y, z in moved)


Added = Callable[[EpisodeSpec, Reference], np.ndarray | None]


def with_model(kind: str) -> Added:
    """The worker's own feed-forward (`compensation`) of the nominal prior or the true model."""

    def added(spec: EpisodeSpec, reference: Reference) -> np.ndarray | None:
        model = (rigid_prior if kind == "rigid" else true_model)(spec.plant)
        return compensation(spec.model_copy(update={"feedforward": "0" * 64}), reference, model)

    return added


CONDITIONS: dict[str, Added] = {
    "PD alone": lambda spec, reference: compensation(spec, reference),
    "+ rigid prior FF": with_model("rigid"),
    "+ true FF": with_model("plant"),
    "+ true FF, delay": lambda s, r: true_compensation(s, r, delay=True),
    "+ true FF, deflection": lambda s, r: true_compensation(s, r, deflection=True),
    "+ true FF, both": lambda s, r: true_compensation(s, r, delay=True, deflection=True),
}


def row_cost(kind: str, plant: str, robot: str = DEFAULT_ROBOT) -> float:
    """µs per row of the model's inverse dynamics over 2,500 random rows, best of 3."""
    rng = np.random.default_rng(0)
    joints = len(robot_of(robot).joint_names)
    q, qd, qdd = (rng.normal(size=(2500, joints)) for _ in range(3))
    model = (rigid_prior if kind == "rigid" else true_model)(plant_preset(plant, robot))
    model.inverse(q[:1], qd[:1], qdd[:1])  # compiles the model once
    best = np.inf
    for _ in range(3):
        started = time.perf_counter()
        model.inverse(q, qd, qdd)
        best = min(best, time.perf_counter() - started)
    return best / len(q) * 1e6


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--plant", type=click.Choice(sorted(PLANTS)), default="realistic", show_default=True)
@click.option("--robot", default=DEFAULT_ROBOT, show_default=True, help="a gainfarm.robots name")
@click.option("--paths", type=click.IntRange(min=1), default=6, show_default=True)
@click.option("--duration", type=click.FloatRange(min=1.0), default=3.0, show_default=True)
def main(plant: str, robot: str, paths: int, duration: float) -> None:
    started = time.perf_counter()
    trajectories = held_out_paths(paths, duration, FIRST_SEED, centres(robot))
    errors: dict[str, list[float]] = {name: [] for name in CONDITIONS}
    # Written out: true_compensation reads the springs of the plant as given.
    gains, nominal = robot_of(robot).default_gains, resolve(plant_preset(plant, robot))
    for path in trajectories:
        reference = reference_for(path, robot)
        spec = EpisodeSpec(gains=gains, trajectory=path, plant=nominal)
        for name, added in CONDITIONS.items():
            scores = score(simulate(spec, reference, added(spec, reference)))
            errors[name].append(scores.f_acc * 1000)
    header = ["condition", *(label(path) for path in trajectories), "mean", "max"]
    click.echo("| " + " | ".join(header) + " |")
    click.echo("|---|" + "---:|" * (len(header) - 1))
    for name, values in errors.items():
        cells = [f"{value:.3f}" for value in (*values, statistics.fmean(values), max(values))]
        click.echo(f"| {name} | " + " | ".join(cells) + " |")
    click.echo(
        f"mean f_acc in mm, {robot}'s default gains, {plant} plant, {duration:g} s paths; "
        f"{time.perf_counter() - started:.1f} s"
    )
    costs = ", ".join(f"{kind} {row_cost(kind, plant, robot):.1f}" for kind in ("rigid", "plant"))
    click.echo(f"inverse dynamics, µs per reference row: {costs}")


if __name__ == "__main__":
    main()
