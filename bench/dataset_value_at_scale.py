"""The dataset-value question at a release's size: do tuned controllers' episodes teach the
arm's dynamics better than the default gains' on the same motions, at equal ticks?

    python bench/dataset_value_at_scale.py RELEASE [--workers 2] [--seeds 3]

The dataset-value experiment (analytic/experiments/dataset_value.py) asks it at the size of a
tuning run's own logs (4,500 ticks a condition). Here the tuned pool is a release's `train`
split (its runs' knees on their tuning trajectories and on the release's excitations, the
runs' own plant); the default pool is the default gains (PD + the robot's gravity compensation
behind FRI) run on the very same train trajectories and plant, on a local farm. Each model
learns the same number of ticks from each (the smaller pool's, drawn with each seed; a fifth
held back for the network's epoch choice) and is scored on two tests: the release's `test`
split (the tuned knees on held-out trajectories) and the default gains on those same held-out
trajectories, beside the floor (the plant's own dynamics) on each. Paired over the seeds (the
same draw's size, the same network seed), a t-test on the difference, Holm over every model and
test; with seeds only varying the draw, it says how steady the difference is, not how it would
vary with other runs.
"""

import sys
import tempfile
from pathlib import Path

import click
import numpy as np
import pyarrow.parquet as pq
from scipy import stats

from gainfarm.analytic.data import learning
from gainfarm.analytic.data.dataset import local_rerun_farm
from gainfarm.analytic.evaluators.batch import batch_jobs, run_batch
from gainfarm.analytic.experiments import dataset_value_measures as dvm
from gainfarm.analytic.experiments.statistics import holm
from gainfarm.models import robot_of
from gainfarm.models.dynamics import true_model
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec


def trajectories(release: Path, split: str) -> list[TrajectorySpec]:
    table = pq.read_table(release / "trajectories.parquet", columns=["spec", "split"])
    return [
        TrajectorySpec.model_validate_json(spec)
        for spec, part in zip(table["spec"].to_pylist(), table["split"].to_pylist(), strict=True)
        if part == split
    ]


def default_gains_rows(
    plant: PlantSpec, specs: list[TrajectorySpec], directory: Path, workers: int
) -> learning.Rows:
    """The default gains (`plant`'s robot's) on every trajectory of `specs`, on `plant`: their
    calm rows."""
    jobs = batch_jobs([robot_of(plant).default_gains], specs, plant)
    with local_rerun_farm(directory, workers) as farm:
        done = run_batch(farm, jobs, directory)
    logs = {e.job_id: Path(e.log) for e in done if e.log is not None}
    if len(logs) != len(jobs):
        sys.exit(f"{len(jobs) - len(logs)} of the default gains' episodes did not run")
    return dvm.pool_rows(logs)


@click.command(help=__doc__.split("\n\n")[0])
@click.argument("release", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--seeds", type=click.IntRange(min=1), default=3, show_default=True)
@click.option("--kinds", default="linear,residual", show_default=True)
def main(release: Path, workers: int, seeds: int, kinds: str) -> None:
    plant = learning.plants(release)[0]
    pools = {"tuned": learning.read_split(release, "train")}
    tests = {"tuned": learning.read_split(release, "test")}
    with tempfile.TemporaryDirectory(prefix="gainfarm-dv-scale-") as scratch:
        for split, pool in (("train", pools), ("test", tests)):
            directory = Path(scratch) / split
            directory.mkdir()
            pool["default"] = default_gains_rows(
                plant, trajectories(release, split), directory, workers
            )
    ticks = min(len(rows) for rows in pools.values())
    print(
        f"pools: tuned {len(pools['tuned']):,} rows, default {len(pools['default']):,}; each "
        f"model learns {ticks:,} of either; tests: tuned {len(tests['tuned']):,} rows, "
        f"default {len(tests['default']):,}"
    )
    floor = true_model(plant)
    for test, rows in tests.items():
        print(f"floor on the {test} test: nMSE {dvm.score(floor, rows)['nmse_mean']:.5f}")
    joints = learning.mean_joints(tests["tuned"].joints)
    span = f"{joints[0]}-{joints[-1]}"
    print(f"| model | learned from | test | nMSE mean ± sd over seeds | RMSE {span} (N·m) |")
    print("|---|---|---|---|---|")
    found: dict[tuple[str, str, str], list[float]] = {}
    for kind in kinds.split(","):
        for seed in range(seeds):
            for name, pool in pools.items():
                train, validation = dvm.subsample(pool, ticks, seed)
                model = dvm.fit_model(kind, plant, train, validation, seed)
                for test, rows in tests.items():
                    scored = dvm.score(model, rows)
                    found.setdefault((kind, name, test), []).append(scored["nmse_mean"])
                    found.setdefault((kind, name, f"{test}-rmse"), []).append(scored["rmse_mean"])
        for test in tests:
            for name in pools:
                nmse, rmse = found[(kind, name, test)], found[(kind, name, f"{test}-rmse")]
                spread = np.std(nmse, ddof=1) if seeds > 1 else 0.0
                print(
                    f"| {kind} | {name} | {test} | {np.mean(nmse):.5f} ± {spread:.5f} "
                    f"| {np.mean(rmse):.3f} |"
                )
    if seeds < 3:
        print("fewer than 3 seeds: no test")
        return
    claims = [(kind, test) for kind in kinds.split(",") for test in tests]
    differences, p = [], []
    for kind, test in claims:
        tuned, default = found[(kind, "tuned", test)], found[(kind, "default", test)]
        differences.append(np.mean(tuned) - np.mean(default))
        p.append(float(stats.ttest_rel(tuned, default).pvalue))
    for (kind, test), difference, raw, adjusted in zip(
        claims, differences, p, holm(p), strict=True
    ):
        print(
            f"{kind}, {test} test: tuned − default {difference:+.5f}, paired t p = {raw:.3g}, "
            f"Holm over the {len(claims)} = {adjusted:.3g} ({seeds} seeds)"
        )


if __name__ == "__main__":
    main()
