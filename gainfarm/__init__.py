"""gainfarm: tune a cobot's torque PD gains with NSGA-II on simulated episodes, on a farm.

    import gainfarm

    run = gainfarm.tune(gainfarm.RunConfig(pop=8, generations=3), out="runs/first")
    for member in run.front():
        print(member.named, member.kp, member.kd)  # {"f_acc": ..., "f_t": ...}: its objectives

One import name over the paper's layers: `gainfarm.analytic` (tuning, evaluators, experiments,
data, view), `gainfarm.worker` (the cobot), `gainfarm.broker` (the router and its lease queue),
`gainfarm.schemas` (the contract), `gainfarm.models` (the robot), and `gainfarm.cli` (what the
three command lines share).

The public face, one list for `gainfarm` and `gainfarm.analytic` (which re-exports this one):
a run's configuration, `tune` to do a run in one call (in the shape
of pymoo's `minimize`) and the run itself, the evaluators that run its episodes (this process,
the farm's client, a `FarmOptions` to start or reach) with the local farm, `read_run` for a run
directory, and `load_dataset` to read a dataset's split for learning. Each name loads on first
use, so that `import gainfarm` costs nothing until one is needed, and `RunConfig` loads no
optimiser, simulator or network library.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

# Each public name and the module that defines it.
WHERE = {
    "RunConfig": "gainfarm.analytic.tuning.config",
    "tune": "gainfarm.analytic.compose",
    "FarmOptions": "gainfarm.analytic.compose",
    "CannotStart": "gainfarm.analytic.compose",
    "TuningInterrupted": "gainfarm.analytic.compose",
    "TuningRun": "gainfarm.analytic.tuning.run",
    "read_run": "gainfarm.analytic.tuning.records",
    "InProcessEvaluator": "gainfarm.analytic.evaluators.inprocess",
    "FarmClient": "gainfarm.analytic.evaluators.farm",
    "FarmUnavailable": "gainfarm.analytic.evaluators.farm",
    "local_farm": "gainfarm.analytic.evaluators.local",
    "load_dataset": "gainfarm.analytic.data.loader",
    "DatasetSplit": "gainfarm.analytic.data.loader",
    "TickDataset": "gainfarm.analytic.data.loader",
}
# The face's names; gainfarm.analytic exports the same (tests/test_import_name.py).
__all__ = [
    "CannotStart",
    "DatasetSplit",
    "FarmClient",
    "FarmOptions",
    "FarmUnavailable",
    "InProcessEvaluator",
    "RunConfig",
    "TickDataset",
    "TuningInterrupted",
    "TuningRun",
    "load_dataset",
    "local_farm",
    "read_run",
    "tune",
]

if TYPE_CHECKING:
    from gainfarm.analytic.compose import CannotStart, FarmOptions, TuningInterrupted, tune
    from gainfarm.analytic.data.loader import DatasetSplit, TickDataset, load_dataset
    from gainfarm.analytic.evaluators.farm import FarmClient, FarmUnavailable
    from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
    from gainfarm.analytic.evaluators.local import local_farm
    from gainfarm.analytic.tuning.config import RunConfig
    from gainfarm.analytic.tuning.records import read_run
    from gainfarm.analytic.tuning.run import TuningRun


def load(name: str, module: str) -> Any:
    """Public name `name` of the face, imported on first use (`module`'s `__getattr__`)."""
    if name not in WHERE:
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    return getattr(import_module(WHERE[name]), name)


def __getattr__(name: str) -> Any:
    return load(name, "gainfarm")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
