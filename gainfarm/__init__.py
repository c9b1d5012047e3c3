"""gainfarm: tune a cobot's torque PD gains with NSGA-II on simulated episodes, on a farm.

    import gainfarm

    run = gainfarm.tune(gainfarm.RunConfig(pop=8, generations=3), out="runs/first")
    for member in run.front():
        print(member.f_acc, member.f_t, member.kp, member.kd)

One import name over the paper's layers: `gainfarm.analytic` (tuning, evaluators, experiments,
data, view), `gainfarm.worker` (the cobot), `gainfarm.broker` (the router and its lease queue),
`gainfarm.schemas` (the contract), `gainfarm.models` (the robot), and `gainfarm.cli` (what the
three command lines share). The names below are `gainfarm.analytic`'s public face; they load on
first use, so that `import gainfarm` costs nothing until one is needed.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

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
    from gainfarm.analytic import (
        FarmClient,
        InProcessEvaluator,
        RunConfig,
        TuningRun,
        local_farm,
        read_run,
        tune,
    )


def __getattr__(name: str) -> Any:
    if name not in __all__:
        raise AttributeError(f"module 'gainfarm' has no attribute {name!r}")
    return getattr(import_module("gainfarm.analytic"), name)
