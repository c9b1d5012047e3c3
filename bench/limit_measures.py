"""The safety measures (schemas/limits.py) of real episodes: what the default gains, smooth
controllers and chattering ones score, on both plants, against the default limits. The
defaults' comments and docs/limits.md quote these numbers.

    python bench/limit_measures.py [--seed 0] [--random 4]

Each controller runs the default 5 s spiral and a 3 s pyramid on the realistic and the ideal
plant: the default gains, three times their stiffness (smooth and accurate), the top of the
search space (three times the stiffness, five times the damping: the chattering end the issue
found on fronts), fifty times the damping, and `--random` gains drawn log-uniformly from the
search space.
"""

import click
import numpy as np

from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import Limits, measures
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.episode import run_episode


def scaled(kp: float, kd: float) -> PDGains:
    return PDGains(
        kp=tuple(kp * gain for gain in DEFAULT_GAINS.kp),
        kd=tuple(kd * gain for gain in DEFAULT_GAINS.kd),
    )


@click.command()
@click.option("--seed", default=0, show_default=True, help="of the random gains")
@click.option("--random", "count", default=4, show_default=True, help="random gains to add")
def main(seed: int, count: int) -> None:
    space = SearchSpace()
    rng = np.random.default_rng(seed)
    controllers = {
        "default": DEFAULT_GAINS,
        "stiff 3x": scaled(3, 1),
        "top 3x/5x": scaled(3, 5),
        "damped 50x": scaled(1, 50),
    } | {f"random {n}": space.gains(rng.uniform(space.lower, space.upper)) for n in range(count)}
    paths = {
        "spiral 5 s": TrajectorySpec(),
        "pyramid 3 s": TrajectorySpec(kind="pyramid", duration=3.0),
    }
    limits = Limits()
    print(
        "plant      path         controller   f_acc mm   f_t       step   sat    speed  "
        "chatter  breaks"
    )
    for plant, model in (("realistic", PLANTS["realistic"]), ("ideal", PLANTS["ideal"])):
        for path_name, path in paths.items():
            for name, gains in controllers.items():
                log = run_episode(EpisodeSpec(gains=gains, trajectory=path, model=model))
                s = score(log)
                broken = ",".join(limits.violated(measures([s]))) or "-"
                print(
                    f"{plant:10} {path_name:12} {name:12} {s.f_acc * 1000:8.2f} {s.f_t:9.3g} "
                    f"{s.torque_step:6.3f} {s.saturated_fraction:6.3f} {s.speed:6.2f} "
                    f"{s.chatter:8.5f}  {broken}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
