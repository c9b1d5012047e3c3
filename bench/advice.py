"""Does the main job's advice hold on the arm you have? Issue 46's targets, measured.

    python bench/advice.py [--seeds 5] [--out bench-advice] [--nominal]

Runs the README's main job (`analytic start --pop 30`, robust by default) for each seed, and a
nominal-only run of the same seed as it was before robust tuning (`--plants 0 --torque-measure
raw`: the anchor of the wall time), then for each seed:

- whether a controller is recommended, and its held-out median and worst error against the
  default gains' (check.json);
- the recommended controller's (else the first candidate's) least tracking-mode damping with the
  command 2 ticks late and the RMS tracking error of A7 on the nominal plant, beside the default
  gains' (worker.stability.margins; the log's q − q_des);
- the recommended controller against the default gains on 18 cases of our own, plants and paths
  no run tuned on: the 5 s spiral, a 6 s Fourier path and a 4 s pyramid, each on the nominal
  plant with one change (2 kg the robot is not told of, a 2-tick delay, 10x rotor inertia,
  doubled friction, halved stiffness) and with all of them (`CASES`): as accurate or not, worse
  in both objectives or not, and whether it chatters (breaks the chatter limit);
- the worst held-out error over the worst on the run's own plants (the nominal and the design's):
  whether the check finds plants much worse than the design's worst;
- the wall time of the robust run over the nominal one's.
"""

import json
import subprocess
import sys
import time
from pathlib import Path

import click
import numpy as np

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.models import resolve
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import Limits, measures
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.episode import run_episode
from gainfarm.worker.job import simulate_batch
from gainfarm.worker.stability import margins

PATHS = {
    "spiral 5 s": TrajectorySpec(kind="spiral", duration=5.0),
    "fourier 6 s": TrajectorySpec(kind="fourier", duration=6.0),
    "pyramid 4 s": TrajectorySpec(kind="pyramid", duration=4.0),
}
NOMINAL = resolve(PlantSpec())  # its numbers written out, for the variants to scale
CHANGES = {
    "payload 2 kg": {"payload": 2.0},
    "delay 2": {"delay": 2},
    "rotor 10x": {"rotor_inertia": tuple(10 * r for r in NOMINAL.rotor_inertia)},
    "friction 2x": {
        "friction": NOMINAL.friction.model_copy(  # type: ignore[union-attr]
            update={
                "coulomb": tuple(2 * c for c in NOMINAL.friction.coulomb),  # type: ignore[union-attr]
                "viscous": tuple(2 * v for v in NOMINAL.friction.viscous),  # type: ignore[union-attr]
            }
        )
    },
    "stiffness 0.5x": {"stiffness": tuple(0.5 * k for k in NOMINAL.stiffness)},
}


def _plant(update: dict) -> PlantSpec:
    from gainfarm.models import min_substeps

    plant = NOMINAL.model_copy(update=update)
    return plant.model_copy(update={"substeps": max(plant.substeps, min_substeps(plant))})


CASES = {
    f"{path}, {name}": (trajectory, _plant(update))
    for path, trajectory in PATHS.items()
    for name, update in [
        *CHANGES.items(),
        ("all", {k: v for u in CHANGES.values() for k, v in u.items()}),
    ]
}


QUICK = ("--generations", "2", "--check-plants", "4")  # --quick: the bench's own test


def _start(seed: int, out: Path, *extra: str) -> float:
    started = time.monotonic()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "gainfarm.analytic",
            "start",
            "--pop",
            "30",
            "--seed",
            str(seed),
            "--out",
            str(out),
            *extra,
        ],
        check=True,
        capture_output=True,
    )
    return time.monotonic() - started


def _a7_lag(gains: PDGains, config: RunConfig) -> float:
    log = run_episode(config.episode_spec(gains, 0))
    return float(np.sqrt(np.mean((log.q[:, 6] - log.q_des[:, 6]) ** 2)))


def _design_worst(gains: PDGains, config: RunConfig) -> float:
    """The largest error of `gains` over the run's own plants (the nominal and the design's)."""
    specs = [config.episode_spec(gains, 0, plant) for plant in range(1 + len(config.plants))]
    return max(outcome.scores.f_acc for outcome in simulate_batch(specs))


def _cases(gains: PDGains, config: RunConfig) -> dict[str, tuple]:
    specs = [
        EpisodeSpec(gains=g, trajectory=t, plant=m, objectives=config.objectives)
        for (t, m) in CASES.values()
        for g in (gains, DEFAULT_GAINS)
    ]
    scores = [outcome.scores for outcome in simulate_batch(specs)]
    limits = Limits()
    found = {}
    for index, name in enumerate(CASES):
        mine, theirs = scores[2 * index], scores[2 * index + 1]
        found[name] = (
            mine.f_acc <= theirs.f_acc,
            mine.f_acc > theirs.f_acc and mine.objectives[1] > theirs.objectives[1],
            "chatter" in limits.violated(measures([mine])) or mine.diverged,
            "chatter" in limits.violated(measures([theirs])) or theirs.diverged,
        )
    return found


@click.command()
@click.option("--seeds", default=5, show_default=True)
@click.option("--out", default="bench-advice", show_default=True, type=click.Path(path_type=Path))
@click.option("--nominal/--no-nominal", default=True, help="time a nominal run of each seed too")
@click.option("--quick", is_flag=True, help="two generations, 4 held-out plants: a smoke test")
def main(seeds: int, out: Path, nominal: bool, quick: bool) -> None:
    out.mkdir(exist_ok=True)
    extra = QUICK if quick else ()
    recommended = 0
    for seed in range(seeds):
        robust = (
            _start(seed, out / f"robust-{seed}", *extra)
            if not (out / f"robust-{seed}").exists()
            else None
        )
        anchor = None
        if nominal and not (out / f"nominal-{seed}").exists():
            anchor = _start(
                seed, out / f"nominal-{seed}", *extra, "--plants", "0", "--torque-measure", "raw"
            )
        run = out / f"robust-{seed}"
        config = RunConfig.model_validate_json((run / "config.json").read_text())
        check = json.loads((run / "check.json").read_text())
        items = check["controllers"]
        default = next(i for i in items if i["row"] is None)
        chosen = next((i for i in items if i["name"] == "recommended"), None)
        recommended += chosen is not None
        shown = chosen or next((i for i in items if i["name"] == "candidate"), None)
        line = f"seed {seed}: " + (
            f"row {chosen['row']} recommended" if chosen else "keep the defaults"
        )
        if robust is not None and anchor is not None:
            line += f"; wall {robust:.0f} s, nominal {anchor:.0f} s: {robust / anchor:.2f}x"
        click.echo(line)
        click.echo(
            f"  held out: default {default['median_f_acc'] * 1e3:.2f} / "
            f"{default['worst_f_acc'] * 1e3:.2f} mm"
        )
        if shown is None:
            continue
        gains = PDGains(kp=shown["kp"], kd=shown["kd"])
        click.echo(
            f"  {shown['name']} row {shown['row']}: {shown['median_f_acc'] * 1e3:.2f} / "
            f"{shown['worst_f_acc'] * 1e3:.2f} mm; {'; '.join(shown['failed']) or 'holds'}"
        )
        late = [
            margins(config.episode_spec(g, 0), delay=2).tracking_at for g in (gains, DEFAULT_GAINS)
        ]
        lags = [_a7_lag(g, config) for g in (gains, DEFAULT_GAINS)]
        click.echo(
            f"  tracking damping 2 ticks late {late[0]:+.3f} (default {late[1]:+.3f}); "
            f"A7 RMS error {lags[0] * 1e3:.1f} mrad (default {lags[1] * 1e3:.1f})"
        )
        design = _design_worst(gains, config), _design_worst(DEFAULT_GAINS, config)
        click.echo(
            "  worst error held out / on the design's plants: "
            f"{shown['worst_f_acc'] / design[0]:.2f} "
            f"(default {default['worst_f_acc'] / design[1]:.2f})"
        )
        cases = _cases(gains, config)
        accurate = sum(c[0] for c in cases.values())
        both = [name for name, c in cases.items() if c[1]]
        chatters = [name for name, c in cases.items() if c[2]]
        defaults_chatter = [name for name, c in cases.items() if c[3]]
        click.echo(
            f"  our {len(cases)} cases: as accurate in {accurate}, worse in both in {len(both)} "
            f"{both}, chatters in {chatters} (the defaults in {defaults_chatter})"
        )
    click.echo(f"recommended in {recommended} of {seeds} seeds")


if __name__ == "__main__":
    main()
