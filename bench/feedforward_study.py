"""PD + learned feed-forward against PD alone, on trajectories neither tuning saw.

    python bench/feedforward_study.py [--out ff-study] [--reps 3] [--pop 12] [--generations 6]
        [--learner linear|residual|mlp|rigid] [--workers 2] [--plant realistic|ideal]

Per repetition r (seed r everywhere), on one local farm, through the library the commands use:
1. tune the PD gains alone (generic: spiral, random and pyramid, 3 s);
2. gather that run's front into a dataset, with its controllers rerun on six fourier excitations
   (`analytic dataset --rerun`), split by trajectory;
3. learn an inverse-dynamics model from it (`analytic learn --kind LEARNER`);
4. tune the PD gains again, same seed, on top of that model (`analytic start --feedforward`);
5. run both fronts on held-out trajectories (random paths and fourier excitations of seeds no
   step above used) and score each controller by its mean f_acc and f_t over them.

The goal is lower error at equal torque smoothness. Reported per repetition: each front's best
error at f_t levels both fronts reach (the error ratio PD / PD+FF there), the knees, and both
fronts' hypervolumes against one reference point (the worst held-out point of the repetition);
across repetitions a paired t-test and Cohen's d_z on the hypervolume difference (with fewer
than three repetitions the data cannot decide). Writes OUT/summary.json and OUT/fronts.png.
"""

import json
import statistics
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import click
import numpy as np
from matplotlib.figure import Figure
from scipy import stats

from gainfarm.analytic.compose import new_study_name
from gainfarm.analytic.data.dataset import build as build_dataset
from gainfarm.analytic.data.learning import learn
from gainfarm.analytic.evaluators.batch import batch_jobs, run_batch
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import hypervolume, non_dominated_indices
from gainfarm.analytic.tuning.records import read_run
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.models.dynamics import digest
from gainfarm.schemas.objectives import NO_EPISODE, objectives
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.trajectory import TrajectorySpec

DURATION = 3.0  # s: the paper's shortest episodes, feasible for every Cartesian kind
TRAINING = tuple(
    TrajectorySpec(kind=kind, duration=DURATION) for kind in ("spiral", "random", "pyramid")
)
EXCITATION = [TrajectorySpec(kind="fourier", seed=200 + i, duration=DURATION) for i in range(6)]
HELD_OUT = [
    TrajectorySpec(kind=kind, seed=1000 + i, duration=DURATION)
    for i in range(2)
    for kind in ("random", "fourier")
]
LEVELS = 5  # f_t levels at which the fronts' errors are compared


@contextmanager
def farm(
    endpoint: str, directory: Path, models: dict[str, bytes] | None = None
) -> Iterator[FarmClient]:
    with FarmClient([endpoint], new_study_name(directory), directory, models=models) as client:
        yield client


def tune(endpoint: str, directory: Path, config: RunConfig, model: bytes | None = None) -> list:
    """The front of a run of `config` (resumed if it is there and unfinished)."""
    if (directory / "config.json").exists():
        run = TuningRun.open(directory)
    else:
        run = TuningRun.create(directory, config, model)
    with run, farm(endpoint, directory, run.models()) as client:
        if not run.finished:
            run.run(client)
    return read_run(directory).front


def held_out(
    endpoint: str, directory: Path, front: list, config: RunConfig, model: bytes | None
) -> list[tuple[float, float]]:
    """Each controller's mean (f_acc, f_t) over the held-out trajectories."""
    wanted = digest(model) if model is not None else None
    jobs = batch_jobs([member.gains for member in front], HELD_OUT, config.model, wanted)
    models = {wanted: model} if model is not None else {}
    directory.mkdir(parents=True, exist_ok=True)
    with farm(endpoint, directory, models) as client:
        found = {e.job_id: e for e in run_batch(client, jobs, directory)}
    points = []
    for index in range(len(front)):
        ids = [job_id for job_id in jobs if job_id.startswith(f"c{index:03d}-")]
        points.append(objectives([found[i].scores if i in found else None for i in ids]))
    return points


def best_error_at(points: list[tuple[float, float]], level: float) -> float:
    """The smallest f_acc among the controllers whose f_t is at most `level`."""
    eligible = [f_acc for f_acc, f_t in points if f_t <= level]
    return min(eligible) if eligible else float("nan")


def knee(points: list[tuple[float, float]]) -> tuple[float, float]:
    """The point nearest the ideal corner once both objectives are scaled to [0, 1]."""
    f = np.log(np.asarray(points))
    scaled = (f - f.min(axis=0)) / np.maximum(np.ptp(f, axis=0), 1e-12)
    return points[int(np.argmin(np.hypot(scaled[:, 0], scaled[:, 1])))]


def compare(pd: list[tuple[float, float]], ff: list[tuple[float, float]]) -> dict[str, object]:
    """One repetition's verdict: errors at common f_t levels, knees, hypervolumes."""
    pd_front = [pd[i] for i in non_dominated_indices(np.asarray(pd))]
    ff_front = [ff[i] for i in non_dominated_indices(np.asarray(ff))]
    both = [p for p in pd + ff if p != NO_EPISODE]
    reference = (max(p[0] for p in both), max(p[1] for p in both))
    # Levels both fronts reach: from the larger of their smallest f_t to the largest f_t.
    low = max(min(p[1] for p in pd_front), min(p[1] for p in ff_front))
    high = max(p[1] for p in both)
    levels = np.geomspace(low, high, LEVELS) if high > low else np.array([low])
    ratios = [best_error_at(pd_front, level) / best_error_at(ff_front, level) for level in levels]
    return {
        "pd": pd,
        "ff": ff,
        "f_t_levels": levels.tolist(),
        "error_ratio_pd_over_ff": ratios,
        "median_error_ratio": float(np.nanmedian(ratios)),
        "pd_knee": knee(pd_front),
        "ff_knee": knee(ff_front),
        "hypervolume_pd": hypervolume(pd_front, reference),
        "hypervolume_ff": hypervolume(ff_front, reference),
    }


def verdict(rows: list[dict[str, object]]) -> dict[str, object]:
    differences = [row["hypervolume_ff"] - row["hypervolume_pd"] for row in rows]
    ratios = [row["median_error_ratio"] for row in rows]
    summary: dict[str, object] = {
        "reps": len(rows),
        "hypervolume_difference_mean": statistics.fmean(differences),
        "median_error_ratio_per_rep": ratios,
    }
    if len(rows) < 3 or statistics.pstdev(differences) == 0:
        summary["test"] = "cannot decide: fewer than three repetitions, or no spread"
        return summary
    test = stats.ttest_rel(
        [row["hypervolume_ff"] for row in rows], [row["hypervolume_pd"] for row in rows]
    )
    summary |= {
        "t": float(test.statistic),
        "p": float(test.pvalue),
        "d_z": statistics.fmean(differences) / statistics.stdev(differences),
        "test": "paired t-test on the held-out hypervolume, PD+FF minus PD",
    }
    return summary


def plot(rows: list[dict[str, object]], path: Path) -> None:
    figure = Figure(figsize=(4 * len(rows), 3.4), layout="constrained")
    for index, row in enumerate(rows):
        axes = figure.add_subplot(1, len(rows), index + 1)
        for name, label, marker in (("pd", "PD alone", "o"), ("ff", "PD + learned FF", "s")):
            points = np.array([p for p in row[name] if p != NO_EPISODE])
            axes.scatter(points[:, 1], points[:, 0] * 1000, marker=marker, label=label, s=18)
        axes.set_xscale("log")
        axes.set_yscale("log")
        axes.set_xlabel("f_t on held-out trajectories, (N·m)²")
        axes.set_ylabel("f_acc, mm")
        axes.set_title(f"seed {index}")
        axes.legend(fontsize=7)
    figure.savefig(path, dpi=110)


@click.command(help=__doc__.split("\n\n")[0])
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("ff-study"),
    show_default=True,
)
@click.option("--reps", type=click.IntRange(min=1), default=3, show_default=True)
@click.option("--pop", type=click.IntRange(min=4), default=12, show_default=True)
@click.option("--generations", type=click.IntRange(min=1), default=6, show_default=True)
@click.option(
    "--learner",
    type=click.Choice(["linear", "residual", "mlp", "rigid"]),
    default="linear",
    show_default=True,
)
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--plant", type=click.Choice(sorted(PLANTS)), default="realistic", show_default=True)
def main(
    out: Path, reps: int, pop: int, generations: int, learner: str, workers: int, plant: str
) -> None:
    started = time.perf_counter()
    rows = []
    with local_farm(workers) as endpoint:
        for seed in range(reps):
            base = out / f"seed{seed}"
            config = RunConfig(
                pop=pop,
                seed=seed,
                trajectories=TRAINING,
                model=PLANTS[plant],
                generations=generations,
                replicate=False,
            )
            pd_front = tune(endpoint, base / "pd", config)
            dataset = base / "dataset"
            if not dataset.exists():
                build_dataset(
                    [base / "pd"],
                    dataset,
                    "front",
                    rerun_trajectories=EXCITATION,
                    farm=lambda directory: farm(endpoint, directory),
                )
            model_dir = base / f"model-{learner}"
            if not model_dir.exists():
                scores = learn(dataset, model_dir, "inverse", learner, seed)
            else:
                scores = json.loads((model_dir / "scores.json").read_text())
            model = (model_dir / "model.npz").read_bytes()
            ff_config = config.model_copy(update={"feedforward": digest(model)})
            ff_front = tune(endpoint, base / "ff", ff_config, model)
            row = compare(
                held_out(endpoint, base / "held-out-pd", pd_front, config, None),
                held_out(endpoint, base / "held-out-ff", ff_front, config, model),
            )
            row["model_test_nmse_mean"] = scores["nmse_mean"]
            rows.append(row)
            click.echo(
                f"seed {seed}: model test nMSE {scores['nmse_mean']:.3f}; held-out error at equal "
                f"f_t, PD / PD+FF: median {row['median_error_ratio']:.2f}x "
                f"({', '.join(f'{r:.2f}' for r in row['error_ratio_pd_over_ff'])}); knees "
                f"PD {row['pd_knee'][0] * 1000:.2f} mm at f_t {row['pd_knee'][1]:.3g}, "
                f"PD+FF {row['ff_knee'][0] * 1000:.2f} mm at f_t {row['ff_knee'][1]:.3g}; "
                f"hypervolume PD {row['hypervolume_pd']:.3f}, PD+FF {row['hypervolume_ff']:.3f}"
            )
    summary = verdict(rows)
    summary["wall_seconds"] = time.perf_counter() - started
    summary["config"] = {
        "reps": reps,
        "pop": pop,
        "generations": generations,
        "learner": learner,
        "plant": plant,
    }
    (out / "summary.json").write_text(json.dumps({"summary": summary, "reps": rows}, indent=1))
    plot(rows, out / "fronts.png")
    click.echo(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
