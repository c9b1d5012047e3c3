"""`tune`: a tuning run in one call, composed as pymoo's `minimize` composes its parts."""

import contextlib
import os
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from analytic.config import RunConfig
from analytic.evaluator import Evaluator
from analytic.farm import FarmClient
from analytic.local import farm_endpoints
from analytic.records import CONFIG_JSON
from analytic.run import RunProgress, TuningRun
from schemas.security import TlsIdentity


def tune(
    config: RunConfig | None = None,
    out: Path | str | None = None,
    *,
    evaluator: Evaluator | None = None,
    connect: Sequence[str] = (),
    workers: int = 1,
    identity: TlsIdentity | None = None,
    on_progress: Callable[[RunProgress], None] = lambda _: None,
) -> TuningRun:
    """Tune the PD gains as `config` says (the defaults: `analytic start`'s) and return the
    finished run; its front is `run.front()`, its files are in `run.directory`.

    The episodes run on `evaluator` if one is given (an InProcessEvaluator, say); else on the
    farm whose broker is at `connect`; else on a local farm of `workers` processes started for
    this call. `out` (default runs/TIME) is the run directory; one that already holds a run of
    the same configuration is resumed (or returned as it is, if finished).
    """
    config = config or RunConfig()
    directory = Path(out) if out is not None else Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    if (directory / CONFIG_JSON).exists():
        run = TuningRun.open(directory)
        if run.config != config:
            raise ValueError(f"{directory} holds a run of another configuration")
    else:
        run = TuningRun.create(directory, config)
    if not run.finished:
        with _evaluator(run.directory, evaluator, connect, workers, identity) as chosen:
            run.run(chosen, on_progress)
    return run


@contextlib.contextmanager
def _evaluator(
    directory: Path,
    evaluator: Evaluator | None,
    connect: Sequence[str],
    workers: int,
    identity: TlsIdentity | None,
) -> Iterator[Evaluator]:
    if evaluator is not None:
        yield evaluator
        return
    with (
        farm_endpoints(connect, workers) as endpoints,
        FarmClient(endpoints, run_study(), directory, identity=identity) as farm,
    ):
        yield farm


def run_study() -> str:
    """The farm's name for this process's tuning run (analytic start, resume, tune)."""
    return f"run-{os.getpid()}"
