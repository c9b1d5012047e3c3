"""The analytic layer: tune a cobot's PD gains with NSGA-II on simulated episodes.

    from analytic import RunConfig, tune

    run = tune(RunConfig(pop=8, generations=3), out="runs/first")
    for member in run.front():
        print(member.f_acc, member.f_t, member.kp, member.kd)

The public surface: a run's configuration and the run itself, `tune` to do it in one call, the
evaluators that run its episodes (the farm's client, this process) with the local farm, and
`read_run` for a run directory. The rest (evolution, records, figures, reports, experiments,
the dataset) is importable by module. Names load on first use, so that importing one module of
the package does not load Zenoh, pymoo and matplotlib with it.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

_WHERE = {
    "RunConfig": "analytic.config",
    "TuningRun": "analytic.run",
    "tune": "analytic.tuning",
    "FarmClient": "analytic.farm",
    "InProcessEvaluator": "analytic.inprocess",
    "local_farm": "analytic.local",
    "read_run": "analytic.records",
}
__all__ = [
    "FarmClient",
    "InProcessEvaluator",
    "RunConfig",
    "TuningRun",
    "local_farm",
    "read_run",
    "tune",
]

if TYPE_CHECKING:
    from analytic.config import RunConfig
    from analytic.farm import FarmClient
    from analytic.inprocess import InProcessEvaluator
    from analytic.local import local_farm
    from analytic.records import read_run
    from analytic.run import TuningRun
    from analytic.tuning import tune


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'analytic' has no attribute {name!r}")
    return getattr(import_module(_WHERE[name]), name)
