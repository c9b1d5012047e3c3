"""The analytic layer: tune a cobot's PD gains with NSGA-II on simulated episodes.

    from analytic import RunConfig, tune

    run = tune(RunConfig(pop=8, generations=3), out="runs/first")
    for member in run.front():
        print(member.f_acc, member.f_t, member.kp, member.kd)

The public surface: the run's configuration and the run itself, `tune` to do it in one call,
and the evaluators that run its episodes (the farm's client, a local farm, this process). The
rest (evolution, records, figures, reports, experiments, dataset) is importable by module.
"""

from analytic.config import RunConfig
from analytic.evaluator import Evaluation, EvaluationStatus, Evaluator
from analytic.farm import FarmClient, FarmUnavailable
from analytic.inprocess import InProcessEvaluator
from analytic.local import local_farm
from analytic.records import FrontMember, RunRecord, read_run
from analytic.run import RunProgress, TuningRun
from analytic.tuning import tune

__all__ = [
    "Evaluation",
    "EvaluationStatus",
    "Evaluator",
    "FarmClient",
    "FarmUnavailable",
    "FrontMember",
    "InProcessEvaluator",
    "RunConfig",
    "RunProgress",
    "RunRecord",
    "TuningRun",
    "local_farm",
    "read_run",
    "tune",
]
