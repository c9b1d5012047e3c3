"""The damping margin (worker/stability.py) of real controllers, what their episodes do, and what
the margin costs an episode. docs/limits.md quotes these numbers.

    python bench/damping.py [--repeats 5] [--poses 8]

Each controller (the default gains, scaled as bench/limit_measures.py scales them) runs the
default 5 s spiral on the realistic and the ideal plant: its least damping ratio beside its
episode's chatter, largest torque step and accuracy. Then the cost: the margin alone against the
whole job (simulate, encode, score; the margin included) on the default episode, medians of
`--repeats`, interleaved so that both meet the same load.
"""

import statistics
import time

import click

from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.episode import run_episode
from gainfarm.worker.job import simulate
from gainfarm.worker.stability import POSES, least_damping


def scaled(kp: float, kd: float) -> PDGains:
    return PDGains(
        kp=tuple(kp * gain for gain in DEFAULT_GAINS.kp),
        kd=tuple(kd * gain for gain in DEFAULT_GAINS.kd),
    )


CONTROLLERS = {
    "default": scaled(1, 1),
    "soft 0.3x": scaled(0.3, 0.3),
    "stiff 3x": scaled(3, 1),
    "damped 3x": scaled(1, 3),
    "top 3x/5x": scaled(3, 5),
    "underdamped 0.1x kd": scaled(1, 0.1),
}


@click.command()
@click.option("--repeats", default=5, show_default=True, help="timed runs of each")
@click.option("--poses", default=POSES, show_default=True, help="poses along the reference")
def main(repeats: int, poses: int) -> None:
    path = TrajectorySpec()
    print("plant      controller           damping   chatter  step    f_acc mm  diverged")
    for plant in ("realistic", "ideal"):
        for name, gains in CONTROLLERS.items():
            spec = EpisodeSpec(gains=gains, trajectory=path, plant=PLANTS[plant])
            s = score(run_episode(spec))
            print(
                f"{plant:10s} {name:20s} {least_damping(spec, poses=poses):+.4f}  "
                f"{s.chatter:7.4f}  {s.torque_step:6.3f}  {s.f_acc * 1e3:8.2f}  {s.diverged}"
            )
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=path)
    simulate(spec)  # warm: the model compiled, the reference cached
    margin, job = [], []
    for _ in range(repeats):
        began = time.perf_counter()
        least_damping(spec, poses=poses)
        margin.append(time.perf_counter() - began)
        began = time.perf_counter()
        simulate(spec)
        job.append(time.perf_counter() - began)
    m, j = statistics.median(margin), statistics.median(job)
    print(
        f"\ncost, default 5 s spiral, realistic plant, {poses} poses: margin {m * 1e3:.1f} ms, "
        f"the job without it {(j - m) * 1e3:.0f} ms: {100 * m / (j - m):.1f} % more"
    )


if __name__ == "__main__":
    main()
