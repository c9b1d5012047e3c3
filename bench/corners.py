"""The sensitivity screen behind robust tuning's designed plants (analytic.tuning.plants.CORNERS):
which ends of the uncertainty ranges break controllers.

    python bench/corners.py [RUN ...] [--every 3] [--trajectory spiral --duration 5]

Each range of models/uncertainty.toml is put at its low and at its high end alone (every joint
alike where it is per joint; the rest nominal), and the default gains and the members of the
fronts of the runs named (every `--every`-th, a nominal run's: the controllers a user was handed)
run the trajectory on each such plant. Per end: how many controllers break a safety limit or
diverge there, and the median and largest factor by which their error grows against their own
on the nominal plant. Then the designed corners run the same controllers, to check that each
breaks what its parts break.
"""

import json
from pathlib import Path

import click
import numpy as np

from gainfarm.analytic.tuning.plants import CORNERS, corner, ranges
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import Limits, measures
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.job import simulate_batch


def controllers(runs: tuple[Path, ...], every: int) -> dict[str, PDGains]:
    found = {"default": DEFAULT_GAINS}
    for run in runs:
        members = json.loads((run / "front.json").read_text())["members"]
        for row, member in enumerate(members, start=1):
            if (row - 1) % every == 0:
                found[f"{run.name}#{row}"] = PDGains(kp=member["kp"], kd=member["kd"])
    return found


def screen(plants: dict[str, PlantSpec], gains: dict[str, PDGains], trajectory: TrajectorySpec):
    names = list(plants)
    specs = [
        EpisodeSpec(gains=g, trajectory=trajectory, plant=plants[p])
        for g in gains.values()
        for p in names
    ]
    scores = [outcome.scores for outcome in simulate_batch(specs)]
    table = np.array(scores, dtype=object).reshape(len(gains), len(names))
    limits = Limits()
    nominal = np.array([s.f_acc if s else np.nan for s in table[:, 0]])
    for column, name in enumerate(names[1:], start=1):
        errors = np.array([s.f_acc if s else np.inf for s in table[:, column]]) / nominal
        broken = [
            limits.violated(measures([s])) if s and not s.diverged else ("diverged",)
            for s in table[:, column]
        ]
        default_broke = ",".join(broken[0]) or "-"
        click.echo(
            f"{name:24s} error x{np.median(errors):6.2f} median, x{np.max(errors):6.2f} worst; "
            f"{sum(1 for b in broken if b):2d}/{len(broken)} break a limit "
            f"({', '.join(sorted({n for b in broken for n in b})) or '-'}); default gains: "
            f"x{errors[0]:.2f} {default_broke}"
        )


@click.command()
@click.argument("runs", nargs=-1, type=click.Path(exists=True, path_type=Path))
@click.option("--every", default=3, show_default=True, help="every n-th front member")
@click.option("--trajectory", default="spiral", show_default=True)
@click.option("--duration", default=5.0, show_default=True)
def main(runs: tuple[Path, ...], every: int, trajectory: str, duration: float) -> None:
    gains = controllers(runs, every)
    path = TrajectorySpec(kind=trajectory, duration=duration)
    nominal = PlantSpec()
    plants = {"nominal": nominal}
    for name in ranges():
        plants[f"{name} low"] = corner(nominal, {name: "low"})
        plants[f"{name} high"] = corner(nominal, {name: "high"})
    click.echo(f"{len(gains)} controllers, {trajectory} {duration:g} s; one end of one range each:")
    screen(plants, gains, path)
    click.echo("the designed corners:")
    screen({"nominal": nominal, **{n: corner(nominal, c) for n, c in CORNERS.items()}}, gains, path)


if __name__ == "__main__":
    main()
