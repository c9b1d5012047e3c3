"""The analytic layer: tune a cobot's PD gains with NSGA-II on simulated episodes.

    from gainfarm.analytic import RunConfig, tune

    run = tune(RunConfig(pop=8, generations=3), out="runs/first")
    for member in run.front():
        print(member.named, member.kp, member.kd)  # {"f_acc": ..., "f_t": ...}: its objectives

Its public names are gainfarm's, one list (gainfarm/__init__.py's `WHERE`), each loaded on first
use, so that importing one module of the package does not load Zenoh, pymoo and matplotlib with
it. The rest (evolution, records, figures, reports, experiments, the dataset) is importable by
module.
"""

from typing import TYPE_CHECKING, Any

from gainfarm import WHERE, load

__all__ = sorted(WHERE)

if TYPE_CHECKING:
    from gainfarm import CannotStart as CannotStart
    from gainfarm import DatasetSplit as DatasetSplit
    from gainfarm import FarmClient as FarmClient
    from gainfarm import FarmOptions as FarmOptions
    from gainfarm import FarmUnavailable as FarmUnavailable
    from gainfarm import InProcessEvaluator as InProcessEvaluator
    from gainfarm import RunConfig as RunConfig
    from gainfarm import TickDataset as TickDataset
    from gainfarm import TuningInterrupted as TuningInterrupted
    from gainfarm import TuningRun as TuningRun
    from gainfarm import load_dataset as load_dataset
    from gainfarm import local_farm as local_farm
    from gainfarm import read_run as read_run
    from gainfarm import tune as tune


def __getattr__(name: str) -> Any:
    return load(name, "gainfarm.analytic")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
