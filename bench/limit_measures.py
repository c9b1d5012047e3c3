"""The safety measures (schemas/limits.py) of real episodes: what the default gains, smooth
controllers and chattering ones score, on both plants, against the default limits. The
defaults' comments and docs/limits.md quote these numbers.

    python bench/limit_measures.py [--seed 0] [--random 4]
    python bench/limit_measures.py --variants 8 [--seed 0]
    python bench/limit_measures.py --variants 8 --runs 9
    python bench/limit_measures.py --variants 8 --fast

Each controller runs the default 5 s spiral and a 3 s pyramid on the realistic and the ideal
plant: the default gains, three times their stiffness (smooth and accurate), the top of the
search space (three times the stiffness, five times the damping: the chattering end the issue
found on fronts), fifty times the damping, and `--random` gains drawn log-uniformly from the
search space.

With `--variants N` it measures instead what the speed, damping and lag limits must allow (issue
46): the default gains, smooth ones (all gains 0.3 times, stiffness 3 times), the defaults with
A7's gains a hundredth (the wrist lag the issue found on fronts), and chattering ones, on the
default 5 s spiral, a fourier and a pyramid path, each on the realistic plant and on
`variants(PlantSpec(), N, seed)` (analytic/tuning/plants.py, a robust run's): each episode's
reference's peak speed and measured peak speed (shares of the data sheet's), least damping ratio
and each joint's RMS lag, then each controller's worst over its episodes. With `--runs R` as well,
the default gains' worst speed and lag per path and least damping and largest chatter on each of
R robust runs' variants (seeds 0 to R − 1), and on a 3 s pyramid; with `--fast`, the default, soft
and stiff gains on each Cartesian kind at its shortest feasible duration (its reference at the
full rated speed, worker.reference) and on a 3 s pyramid, on the realistic plant and the variants.
"""

import click
import numpy as np

from gainfarm.analytic.tuning.plants import variants
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import Limits, measures
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PLANTS, SPEED_LIMITS, PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.episode import run_episode
from gainfarm.worker.reference import shortest_duration

PATHS = {
    "spiral": TrajectorySpec(),
    "fourier": TrajectorySpec(kind="fourier"),
    "pyramid": TrajectorySpec(kind="pyramid"),
}


def scaled(kp: float, kd: float) -> PDGains:
    return PDGains(
        kp=tuple(kp * gain for gain in DEFAULT_GAINS.kp),
        kd=tuple(kd * gain for gain in DEFAULT_GAINS.kd),
    )


def wrist(share: float) -> PDGains:
    """The default gains with A7's (the last joint's) scaled by `share`."""
    return PDGains(
        kp=(*DEFAULT_GAINS.kp[:-1], share * DEFAULT_GAINS.kp[-1]),
        kd=(*DEFAULT_GAINS.kd[:-1], share * DEFAULT_GAINS.kd[-1]),
    )


def robust(seed: int, count: int) -> None:
    """The speed, damping and lag of each controller's episodes on the nominal plant and
    `count` variants, then its worst over them (a robust run's measures)."""
    controllers = {
        "default": DEFAULT_GAINS,
        "soft 0.3x": scaled(0.3, 0.3),
        "stiff 3x": scaled(3, 1),
        "A7 /100": wrist(0.01),
        "kd 0.1x": scaled(1, 0.1),
        "top 3x/5x": scaled(3, 5),
    }
    paths = PATHS
    plants = {"nominal": PlantSpec()} | {
        f"variant {n}": plant for n, plant in enumerate(variants(PlantSpec(), count, seed))
    }
    limit = np.asarray(SPEED_LIMITS)
    print("controller  path     plant       ref spd  speed  damping  lag per joint, mrad RMS")
    for name, gains in controllers.items():
        worst = {"ref": 0.0, "speed": 0.0, "damping": 1.0, "lag": np.zeros(7)}
        for path_name, path in paths.items():
            for plant_name, plant in plants.items():
                log = run_episode(EpisodeSpec(gains=gains, trajectory=path, plant=plant))
                s = score(log)
                ref = float(np.max(np.abs(log.qd_des) / limit))
                lag = np.sqrt(np.mean((log.q - log.q_des) ** 2, axis=0)) * 1000
                worst["ref"] = max(worst["ref"], ref)
                worst["speed"] = max(worst["speed"], s.speed)
                worst["damping"] = min(worst["damping"], float(s.damping or -1.0))
                worst["lag"] = np.maximum(worst["lag"], lag)
                print(
                    f"{name:11} {path_name:8} {plant_name:10} {ref:7.3f} {s.speed:6.3f} "
                    f"{s.damping:+8.4f}  " + " ".join(f"{v:6.2f}" for v in lag),
                    flush=True,
                )
        print(
            f"{name:11} WORST                 {worst['ref']:7.3f} {worst['speed']:6.3f} "
            f"{worst['damping']:+8.4f}  " + " ".join(f"{v:6.2f}" for v in worst["lag"]),
            flush=True,
        )


def runs(count: int, runs: int) -> None:
    """The default gains' worst measures over each of `runs` robust runs' `count` variants."""
    paths = PATHS | {"pyramid 3 s": TrajectorySpec(kind="pyramid", duration=3.0)}
    for seed in range(runs):
        lag: dict[str, float] = {}
        speed: dict[str, float] = {}
        damping, chatter = 1.0, 0.0
        for plant in variants(PlantSpec(), count, seed):
            for name, path in paths.items():
                s = score(
                    run_episode(EpisodeSpec(gains=DEFAULT_GAINS, trajectory=path, plant=plant))
                )
                lag[name] = max(lag.get(name, 0.0), s.lag)
                speed[name] = max(speed.get(name, 0.0), s.speed)
                if name in PATHS:  # the 5 s paths
                    damping, chatter = (
                        min(damping, float(s.damping or -1.0)),
                        max(chatter, s.chatter),
                    )
        print(
            f"seed {seed}: lag mrad "
            + " ".join(f"{k} {v * 1000:.1f}" for k, v in lag.items())
            + f"; least damping {damping:+.4f}; largest chatter {chatter:.4f}; speed "
            + " ".join(f"{k} {v:.3f}" for k, v in speed.items()),
            flush=True,
        )


def fast(count: int) -> None:
    """Default, soft and stiff gains on references at (nearly) the full rated speed."""
    controllers = {
        "default": DEFAULT_GAINS,
        "soft 0.3x": scaled(0.3, 0.3),
        "stiff 3x": scaled(3, 1),
    }
    plants = (PlantSpec(), *variants(PlantSpec(), count, 0))
    limit = np.asarray(SPEED_LIMITS)
    paths = [
        TrajectorySpec(kind=kind, duration=shortest_duration(TrajectorySpec(kind=kind)))
        for kind in ("spiral", "pyramid", "random")
    ] + [TrajectorySpec(kind="pyramid", duration=3.0)]
    for path in paths:
        for name, gains in controllers.items():
            speeds = []
            for plant in plants:
                log = run_episode(EpisodeSpec(gains=gains, trajectory=path, plant=plant))
                speeds.append(score(log).speed)
            ref = float(np.max(np.abs(log.qd_des) / limit))
            print(
                f"{path.kind:8} {path.duration:.1f} s, reference {ref:.3f}: {name:10} "
                f"nominal {speeds[0]:.3f}, variants up to {max(speeds[1:]):.3f}",
                flush=True,
            )


@click.command()
@click.option("--seed", default=0, show_default=True, help="of the random gains, or the variants")
@click.option("--random", "count", default=4, show_default=True, help="random gains to add")
@click.option(
    "--variants",
    "plants",
    default=0,
    show_default=True,
    help="measure speed, damping and lag on the nominal plant and this many variants instead",
)
@click.option(
    "--runs", "run_count", default=0, help="with --variants: the default gains on this many runs'"
)
@click.option("--fast", "at_rated", is_flag=True, help="with --variants: rated-speed references")
def main(seed: int, count: int, plants: int, run_count: int, at_rated: bool) -> None:
    if plants and run_count:
        runs(plants, run_count)
        return
    if plants and at_rated:
        fast(plants)
        return
    if plants:
        robust(seed, plants)
        return
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
        "chatter  lag mrad  breaks"
    )
    for plant, model in (("realistic", PLANTS["realistic"]), ("ideal", PLANTS["ideal"])):
        for path_name, path in paths.items():
            for name, gains in controllers.items():
                log = run_episode(EpisodeSpec(gains=gains, trajectory=path, plant=model))
                s = score(log)
                broken = ",".join(limits.violated(measures([s]))) or "-"
                print(
                    f"{plant:10} {path_name:12} {name:12} {s.f_acc * 1000:8.2f} {s.f_t:9.3g} "
                    f"{s.torque_step:6.3f} {s.saturated_fraction:6.3f} {s.speed:6.2f} "
                    f"{s.chatter:8.5f} {s.lag * 1000:8.1f}  {broken}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
