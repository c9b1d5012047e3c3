"""The analytic layer: tune a cobot's PD gains with NSGA-II on simulated episodes.

    from gainfarm.analytic import RunConfig, tune

    run = tune(RunConfig(pop=8, generations=3), out="runs/first")
    for member in run.front():
        print(member.f_acc, member.f_t, member.kp, member.kd)

The public surface: a run's configuration and the run itself, `tune` to do it in one call, the
evaluators that run its episodes (the farm's client, this process) with the local farm,
`read_run` for a run directory, and `load_dataset` to read a dataset's split for learning
(`DatasetSplit`, `TickDataset`). The rest (evolution, records, figures, reports, experiments,
the dataset) is importable by module. Names load on first use, so that importing one module of
the package does not load Zenoh, pymoo and matplotlib with it.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

_WHERE = {
    "RunConfig": "gainfarm.analytic.tuning.config",
    "TuningRun": "gainfarm.analytic.tuning.run",
    "tune": "gainfarm.analytic.compose",
    "FarmClient": "gainfarm.analytic.evaluators.farm",
    "InProcessEvaluator": "gainfarm.analytic.evaluators.inprocess",
    "local_farm": "gainfarm.analytic.evaluators.local",
    "read_run": "gainfarm.analytic.tuning.records",
    "load_dataset": "gainfarm.analytic.data.loader",
    "DatasetSplit": "gainfarm.analytic.data.loader",
    "TickDataset": "gainfarm.analytic.data.loader",
}
__all__ = [
    "DatasetSplit",
    "FarmClient",
    "InProcessEvaluator",
    "RunConfig",
    "TickDataset",
    "TuningRun",
    "load_dataset",
    "local_farm",
    "read_run",
    "tune",
]

if TYPE_CHECKING:
    from gainfarm.analytic.compose import tune
    from gainfarm.analytic.data.loader import DatasetSplit, TickDataset, load_dataset
    from gainfarm.analytic.evaluators.farm import FarmClient
    from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
    from gainfarm.analytic.evaluators.local import local_farm
    from gainfarm.analytic.tuning.config import RunConfig
    from gainfarm.analytic.tuning.records import read_run
    from gainfarm.analytic.tuning.run import TuningRun


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'gainfarm.analytic' has no attribute {name!r}")
    return getattr(import_module(_WHERE[name]), name)
