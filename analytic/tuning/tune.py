"""`tune`: a tuning run in one call, composed as pymoo's `minimize` composes its parts."""

import contextlib
import re
import secrets
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import farm_endpoints
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import CONFIG_JSON
from gainfarm.analytic.tuning.run import RunProgress, TuningRun
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.wire import NAME_PATTERN

OWNER = re.compile(r"[A-Za-z0-9_-]{1,32}")  # a participant name of the secure profile
STUDY_RANDOM_HEX = 8


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
    the same configuration is resumed (or returned as it is, if finished). The run returned is
    closed (analytic.run: another process may open it); `TuningRun.open` it to write it again.
    RunBusy if another process is running it.
    """
    config = config or RunConfig()
    directory = Path(out) if out is not None else Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    if (directory / CONFIG_JSON).exists():
        run = TuningRun.open(directory)
        if run.config != config:
            run.close()
            raise ValueError(f"{directory} holds a run of another configuration")
    else:
        run = TuningRun.create(directory, config)
    with run:
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
        FarmClient(endpoints, new_study_name(directory), directory, identity=identity) as farm,
    ):
        yield farm


def new_study_name(directory: Path, owner: str | None = None) -> str:
    """A farm study name for work on `directory` (a run's, a batch's): `[OWNER.]SLUG-RANDOM`,
    SLUG the directory's name made safe, RANDOM 8 hex digits new on every call.

    Unique with no coordination (32 random bits): two processes on one farm (two containers
    are both PID 1), even of directories of one name, do not share a name, which the broker
    would refuse the second of. A resume takes a new name too: nothing of the farm's is kept
    across it (the broker drops a study's queue when its client goes, and the resumed run
    submits again every job it still needs), and the old process's liveliness token may
    outlive it a while, which would refuse the old name. `owner`, a participant name of the
    secure profile (letters, digits, _ and -), prefixes the name so that a farm can scope
    studies per identity.
    """
    if owner is not None and not OWNER.fullmatch(owner):
        raise ValueError(f"study owner {owner!r}: 1 to 32 letters, digits, _ or -")
    prefix = f"{owner}." if owner else ""
    # Only A-Z a-z 0-9 _ -: no dot, so the first dot always ends the owner.
    slug = re.sub(r"[^A-Za-z0-9_]+", "-", Path(directory).absolute().name).strip("-") or "run"
    room = 64 - len(prefix) - 1 - STUDY_RANDOM_HEX
    name = f"{prefix}{slug[:room].rstrip('-') or 'run'}-{secrets.token_hex(STUDY_RANDOM_HEX // 2)}"
    assert re.fullmatch(NAME_PATTERN, name), name  # the wire's rule, so a key chunk
    return name
