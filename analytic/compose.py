"""`tune`: a tuning run in one call, composed as pymoo's `minimize` composes its parts: the loop
(analytic.tuning), an evaluator (analytic.evaluators) and the run's report (analytic.view). The one
composition root, on its own floor above those three: `analytic start` is `tune` with a progress
display, so what a run checks and decides before it starts (the trajectories' feasibility, a
generic run's balance, the run directory's claim) is the same from Python and from the command
line."""

import contextlib
import importlib
import math
import re
import secrets
import shutil
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path

from pydantic import ValidationError

from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.evaluators.farm import FarmClient, FarmUnavailable
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import LocalFarm, farm_endpoints
from gainfarm.analytic.tuning.check import CheckPlan, read_check, run_check
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import CONFIG_JSON, REPORT_MD
from gainfarm.analytic.tuning.run import RunProgress, TuningRun
from gainfarm.cli import interrupts
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.limits import Limits, measures
from gainfarm.schemas.objectives import balancing_weights, plant_scales
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.wire import NAME_PATTERN, describe

OWNER = re.compile(r"[A-Za-z0-9_-]{1,32}")  # a participant name of the secure profile
STUDY_RANDOM_HEX = 8

# Given the evaluator a run goes on, what to enter for the run: it yields the progress callback
# (`analytic start` shows the farm's workers and waits beside the run's progress).
Watch = Callable[[Evaluator], AbstractContextManager[Callable[[RunProgress], None]]]


class CannotStart(ValueError):
    """A new run that cannot start, said in one line; `part` is what is wrong: "out" (the run
    directory), "duration" or "placement" (a trajectory the arm cannot follow: too fast for its
    limits, or out of its reach), "balance" (a generic run with nothing to balance by),
    "algorithm" (one this installation cannot run), or the option that gave a part of the config
    that is no longer valid ("uncertainty" for a plant variant, "plant")."""

    def __init__(self, message: str, part: str):
        super().__init__(message)
        self.part = part


# What a run does after its evolution, in order (`TuningInterrupted.stage`), as a Ctrl-C says it.
STAGES = {
    "evolution": "the evolution",
    "validation": "the front's validation",
    "baseline": "the default gains' episodes",
    "check": "the held-out check",
    "report": "the figures and report",
}


class TuningInterrupted(KeyboardInterrupt):
    """Ctrl-C during `tune`: `run` is the run, to go on with later (`tune` again, or `analytic
    resume`); None if the run was new and nothing of it had run, so nothing of it is left.
    `stage`: what it was doing (a key of STAGES); after "evolution", its evolution is over and
    saved, and a resume does only what is left."""

    def __init__(self, run: TuningRun | None, stage: str = "evolution"):
        super().__init__()
        self.run = run
        self.stage = stage


def complete(run: TuningRun) -> bool:
    """Whether `run` has nothing left to do: its evolution finished, and what follows it (the
    front's validation, the default gains' episodes, the held-out check) was done and drawn:
    report.md is written last."""
    return run.finished and (run.directory / REPORT_MD).exists() and not _check_missing(run)


def _check_missing(run: TuningRun) -> bool:
    return bool(run.config.check_plants and run.front() and read_check(run.directory) is None)


def _needs_evaluator(run: TuningRun) -> bool:
    """Whether a finished run has episodes left to run before its report."""
    return run.validation_pending() or run.baseline() is None or _check_missing(run)


@dataclass(frozen=True)
class FarmOptions:
    """Where a run's episodes run when `tune` is given no evaluator object: a farm, its options.
    Its broker at `connect` (a secure farm's: with the analytic participant `identity`); else a
    local farm of `workers` processes (None: one per core) started for the call, or `local` if
    given: one its caller started early, so that its processes start while this one imports and
    checks the run (`tune` stops it when done with it). `models`: the feed-forward model files
    the config may name, by SHA-256 (as InProcessEvaluator takes them)."""

    connect: Sequence[str] = ()
    workers: int | None = None
    identity: TlsIdentity | None = None
    local: LocalFarm | None = None
    models: Mapping[str, bytes] = field(default_factory=dict)


def tune(
    config: RunConfig | None = None,
    out: Path | str | None = None,
    evaluator: Evaluator | FarmOptions | None = None,
) -> TuningRun:
    """Tune the PD gains as `config` says (the defaults: `analytic start`'s) and return the
    finished run; its front is `run.front()`, its files are in `run.directory`. In the shape of
    pymoo's `minimize(problem, algorithm, termination)`: what decides the outcome is `config`
    (RunConfig, balancing included), where the episodes run is `evaluator`.

    The episodes run on `evaluator` (an InProcessEvaluator, say), or on the farm `FarmOptions`
    say; None: a local farm of one worker process per core, started for this call. The
    feed-forward model file `config.feedforward` names comes with the evaluator (its
    `models`). `out` (default runs/TIME) is the run directory: new or empty, or one that
    already holds a run of the same configuration, which is resumed (or returned as it is, if
    finished).

    A new run is checked before anything is written (CannotStart: a trajectory the arm cannot
    follow, nothing to balance by, `out` taken); if the farm cannot be had (FarmUnavailable) or
    anything else stops it before any job is sent, nothing of it is left. A Ctrl-C once the run
    is made leaves as TuningInterrupted, which says whether there is a run to go on with. The run
    returned is closed (analytic.tuning.run: another process may open it); `TuningRun.open` it
    to write it again. RunBusy if another process is running it.
    """
    config = config or RunConfig()
    where = evaluator if evaluator is not None else FarmOptions()
    models: Mapping[str, bytes] = getattr(where, "models", {})
    feedforward = models.get(config.feedforward) if config.feedforward else None
    run, forget = make_run(config, out, feedforward)
    tune_run(run, where, forget=forget)
    return run


def make_run(
    config: RunConfig, out: Path | str | None = None, feedforward: bytes | None = None
) -> tuple[TuningRun, Callable[[], None] | None]:
    """The run `tune` goes on with, open: the one in `out` if it holds a run of `config`
    (resumed; ValueError if of another), else a new one, checked and balanced first (see
    `tune`), with what removes it again if nothing of it runs (`tune_run`'s `forget`; None for
    a run that was there). `feedforward`: the model file `config.feedforward` names."""
    directory = Path(out) if out is not None else new_directory()
    if (directory / CONFIG_JSON).exists():
        run = TuningRun.open(directory)
        if run.config not in (config, _balance_of(config, run.config)):
            run.close()
            raise ValueError(f"{directory} holds a run of another configuration")
        return run, None
    check_followable(config.trajectories, config.robot)
    if config.balance and _unbalanced(config):
        config = balanced(config, feedforward)
    forget = claim(directory)
    return _create(directory, config, feedforward, forget), forget


def tune_run(
    run: TuningRun,
    evaluator: Evaluator | FarmOptions | None = None,
    *,
    on_progress: Callable[[RunProgress], None] = lambda _: None,
    watch: Watch | None = None,
    forget: Callable[[], None] | None = None,
    on_check: Callable[[CheckPlan], None] = lambda _: None,
) -> str:
    """Run `run` (open, so holding its lock) to its end on `evaluator` (an evaluator, or the
    `FarmOptions` to use; None: a local farm), evaluate the default gains beside it (baseline.json),
    check the controllers it names on held-out plants (check.json, if its config holds any;
    `on_check` told as it starts), draw its figures and report.md, and close it; return why it
    stopped. A run whose evolution has finished does only what is left of that (what a Ctrl-C
    after the evolution left). `watch`: see `Watch`; else `on_progress` is called after every
    evaluation. `forget`, for a run just made: what removes it if nothing of it runs (the farm
    cannot be had, Ctrl-C or any failure before a job is sent). A Ctrl-C leaves as
    TuningInterrupted."""
    begun = False
    stage = "evolution"
    try:
        # A local farm stops while the report is drawn; `stopping` waits for it after, and for
        # the figures, drawn while the held-out check runs.
        with run, contextlib.ExitStack() as stopping:
            figures = _Figures()
            stopping.callback(figures.wait)
            if complete(run):
                return run.state.stopped or ""
            if not run.finished or _needs_evaluator(run):
                chosen_farm = _evaluator(
                    run, evaluator if evaluator is not None else FarmOptions(), stopping
                )
                with chosen_farm as chosen:
                    begun = True
                    shown = watch(chosen) if watch else contextlib.nullcontext(on_progress)
                    with shown as step:
                        # A finished run's evolution is not run again: only a validation
                        # a Ctrl-C cut short goes on.
                        run.run(chosen, _loading_figures(step))
                        stage = "baseline"
                        run.baseline(chosen)
                        if read_check(run.directory) is None:
                            stage = "check"
                            run_check(run, chosen, on_check)
                        # After the check: the controller the figure marks is its advice.
                        figures.begin(run)
            stage = "report"
            figures.finish(run)
            return run.state.stopped or ""
    except BaseException as error:
        # What a Ctrl-C or SIGTERM broke on its way out (a KeyboardInterrupt that a C extension's
        # call turned into an error of its own) is the stop's doing: the run is as resumable.
        stopped = isinstance(error, KeyboardInterrupt) or interrupts.INTERRUPTED.is_set()
        if not begun and forget is not None:  # nothing of a new run ran: nothing of it is left
            forget()
            if stopped:
                raise TuningInterrupted(None) from None
            raise
        if stopped:
            if stage == "evolution" and run.saved_stopped:  # stopped, then its front validated
                stage = "validation"
            raise TuningInterrupted(run, stage) from None
        raise


# The option that gave each part of a config that a command may have made without validating it
# (a plant variant with the physics steps it needs, a plant told of a load).
_PARTS = {"plants": "uncertainty", "check_plants": "uncertainty", "plant": "plant"}


def _create(
    directory: Path, config: RunConfig, feedforward: bytes | None, forget: Callable[[], None]
) -> TuningRun:
    try:
        return TuningRun.create(directory, config, feedforward)
    except FileExistsError as error:
        raise CannotStart(str(error), "out") from None
    except OSError as error:
        forget()
        where = str(error.filename or directory)
        raise CannotStart(f"cannot write {where!r}: {error.strerror}", "out") from None
    except ValidationError as error:  # the config checked once more: a part given unchecked
        field = str((error.errors()[0]["loc"] or ("config",))[0])
        raise CannotStart(describe(error), _PARTS.get(field, field.replace("_", "-"))) from None
    except ValueError as error:  # an algorithm this installation cannot run (agemoea2: numba)
        raise CannotStart(str(error), "algorithm") from None
    except KeyboardInterrupt:
        forget()
        raise TuningInterrupted(None) from None


def _unbalanced(config: RunConfig) -> bool:
    """Whether `balanced` has something to do for `config`: trajectories to weigh, or plants to
    scale, that it was not given weights or scales for."""
    trajectories = len(config.trajectories) > 1 and config.objective_weights is None
    return trajectories or bool(config.plants and config.plant_scales is None)


def _balance_of(config: RunConfig, found: RunConfig) -> RunConfig | None:
    """`config` with the weights and scales a balanced run in its directory found, if `tune`
    would have balanced it: what it is resumed as."""
    if not config.balance or not _unbalanced(config):
        return None
    update = {}
    if len(config.trajectories) > 1 and config.objective_weights is None:
        update["objective_weights"] = found.objective_weights
    if config.plants and config.plant_scales is None:
        update["plant_scales"] = found.plant_scales
    return config.model_copy(update=update)


class _Figures:
    """A run's figures, drawn on a thread of their own once its default gains have run and its
    held-out check has advised (what they show is then settled), while its farm stops:
    only report.md is left for its end. What draws them is loaded in the function, not at the
    top: matplotlib is half a second of a run's start, before its first job."""

    def __init__(self) -> None:
        self._thread: threading.Thread | None = None
        self._failed: list[BaseException] = []

    def begin(self, run: TuningRun) -> None:
        self._thread = threading.Thread(target=self._draw, args=(run,), name="figures")
        self._thread.start()

    def _draw(self, run: TuningRun) -> None:
        try:
            # start-up: matplotlib (half a second) loads once the run's first results are in
            from gainfarm.analytic.view.run_report import draw_figures

            draw_figures(run)
        except BaseException as error:  # raised again by `finish`, in the run's thread
            self._failed.append(error)

    def wait(self) -> None:
        if self._thread is not None:
            self._thread.join()

    def finish(self, run: TuningRun) -> None:
        """The report: the figures drawn (here, if they were not begun), then report.md."""
        # start-up: matplotlib, as in `_draw`
        from gainfarm.analytic.view.run_report import write_run_report

        self.wait()
        if self._failed:
            raise self._failed[0]
        write_run_report(run, figures=self._thread is None)


def _loading_figures(step: Callable[[RunProgress], None]) -> Callable[[RunProgress], None]:
    """`step`, which also loads what draws the report, on a thread of its own, once the first
    result is in: the run's end then need not wait for the import (half a second), and its
    start (the imports of its worker processes, its first jobs) does not share the cores
    with it."""
    loading: list[threading.Thread] = []

    def stepped(progress: RunProgress) -> None:
        if not loading:
            loading.append(threading.Thread(target=_load_figures, name="load-figures", daemon=True))
            loading[0].start()
        step(progress)

    return stepped


def _load_figures() -> None:
    with contextlib.suppress(Exception):  # whatever fails here fails again, and is said there
        importlib.import_module("gainfarm.analytic.view.run_report")


@contextlib.contextmanager
def _evaluator(
    run: TuningRun, where: Evaluator | FarmOptions, stopping: contextlib.ExitStack
) -> Iterator[Evaluator]:
    """The evaluator `where` is, or else the client of the farm it says (FarmUnavailable if
    the farm cannot be had; what goes wrong later in the block is not relabelled). A local farm
    (`where.local`, or one started here) begins to stop as the block ends, and `stopping` waits
    for it."""
    if not isinstance(where, FarmOptions):
        yield where
        return
    connect, workers, identity, farm = where.connect, where.workers, where.identity, where.local
    try:
        models = run.models()
    except ValueError as error:  # its feed-forward model file is missing or another
        raise CannotStart(f"{str(run.directory)!r}: {error}", "out") from None
    if not connect:
        farm = farm or LocalFarm(workers, robot=run.config.robot)
        stopping.callback(farm.stop)
    with contextlib.ExitStack() as stack:
        try:
            endpoints = stack.enter_context(farm_endpoints(connect, workers, farm))
            client = stack.enter_context(
                FarmClient(
                    endpoints,
                    new_study_name(run.directory, identity.name if identity else None),
                    run.directory,
                    identity=identity,
                    models=models,
                    # keep="front": the workers keep the logs, and the front's are fetched.
                    keep_logs=run.config.keep == "all",
                    trusted=not connect,  # a local farm of this process's own workers
                    # ... and none other: a result from any other worker is refused
                    own_workers=None if connect or farm is None else farm.names,
                )
            )
        except (ValueError, ConnectionError) as error:
            if isinstance(error, FarmUnavailable):
                raise
            raise FarmUnavailable(str(error)) from error
        yield client


def new_directory() -> Path:
    """A new run's directory, when none is given: runs/TIME."""
    return Path("runs") / time.strftime("%Y%m%d-%H%M%S")


def check_followable(trajectories: Iterable[TrajectorySpec], robot: str = DEFAULT_ROBOT) -> None:
    """CannotStart, in one line, for a trajectory `robot` cannot follow (out of reach, or too
    fast for its limits), before any job is sent: every episode of it would fail."""
    # start-up: SciPy's interpolation loads when a new run is checked, not with `tune`
    from gainfarm.worker import ik, reference

    for trajectory in trajectories:
        try:
            reference.reference_for(trajectory, robot)
        except reference.InfeasibleReference as error:
            raise CannotStart(str(error), "duration") from None
        except ik.UnreachablePath as error:
            raise CannotStart(str(error), "placement") from None


def balanced(config: RunConfig, feedforward: bytes | None = None) -> RunConfig:
    """`config` with its objectives balanced by the default gains' scores, simulated in this
    process (a few episodes, before any farm is asked for): a generic objective's trajectories
    weighed alike (schemas.objectives.balancing_weights), a robust run's plants scaled alike
    (schemas.objectives.plant_scales), each unless `config` gives them. CannotStart if the
    default gains do not finish a trajectory of a generic run on the nominal plant (a plant
    they do not finish is left unscaled)."""
    plants = 1 + len(config.plants)
    pairs = [(t, p) for t in range(len(config.trajectories)) for p in range(plants)]
    models = {config.feedforward: feedforward} if config.feedforward and feedforward else {}
    with InProcessEvaluator(models=models) as evaluator:
        defaults = config.default_gains  # the robot's
        evaluator.submit({f"t{t}-p{p}": config.episode_spec(defaults, t, p) for t, p in pairs})
        found = {result.job_id: result.scores for result in evaluator.results()}
    update = {}
    if len(config.trajectories) > 1 and config.objective_weights is None:
        reference = []
        for index, trajectory in enumerate(config.trajectories):
            scores = found[f"t{index}-p0"]
            if scores is None or scores.diverged:
                raise CannotStart(
                    f"the default gains do not finish the {trajectory.kind} trajectory, so "
                    "there is nothing to balance by",
                    "balance",
                )
            reference.append(scores.objectives)  # the run's two, a plug-in's included
        update["objective_weights"] = balancing_weights(reference)
    if config.plants and config.plant_scales is None:
        # A plant the default gains diverge on is left unscaled (its penalty as it is).
        each = [
            (math.nan, math.nan)
            if (s := found[f"t{t}-p{p}"]) is None or s.diverged
            else s.objectives
            for t, p in pairs
        ]
        update["plant_scales"] = plant_scales(each, plants)
    return RunConfig.model_validate(config.model_dump() | update)


def defaults_hold(
    trajectories: Sequence[TrajectorySpec], limits: Limits, objectives: tuple[str, str]
) -> Callable[[PlantSpec], bool]:
    """Whether the robot's default gains keep to `limits` on a plant, on every one of
    `trajectories` (simulated in this process: an episode each): what a designed corner of
    robust tuning must let them do (analytic.tuning.plants.held_design)."""

    def holds(plant: PlantSpec) -> bool:
        # start-up: the robot's module loads with the plant's first episode
        from gainfarm.models import resolve, robot_of

        plant = resolve(plant)  # as the worker logs it, which the evaluator checks
        defaults = robot_of(plant).default_gains
        specs = {
            f"t{index}": EpisodeSpec(
                gains=defaults, trajectory=trajectory, plant=plant, objectives=objectives
            )
            for index, trajectory in enumerate(trajectories)
        }
        with InProcessEvaluator() as evaluator:
            evaluator.submit(specs)
            scores = [result.scores for result in evaluator.results()]
        if any(score is None or score.diverged for score in scores):
            return False
        return not limits.violated(measures(scores))

    return holds


def claim(directory: Path) -> Callable[[], None]:
    """Check that `directory` is new or empty (CannotStart saying why not); return what removes
    everything then put there, for a start that fails before anything runs: the directory, with
    the parents it needed, or only what is in it if it was there."""
    if directory.exists() and not directory.is_dir():
        raise CannotStart(f"{str(directory)!r} is a file, not a directory", "out")
    try:
        if directory.is_dir() and any(directory.iterdir()):
            raise CannotStart(
                f"{str(directory)!r} is not empty: choose a new or an empty directory", "out"
            )
    except OSError as error:
        raise CannotStart(f"cannot read {str(directory)!r}: {error.strerror}", "out") from None
    new = None  # the outermost directory this command will make
    ancestor = directory
    while not ancestor.exists():
        new, ancestor = ancestor, ancestor.parent

    def forget() -> None:
        if new is not None:
            shutil.rmtree(new, ignore_errors=True)
            return
        for child in directory.iterdir():
            if child.is_dir() and not child.is_symlink():
                shutil.rmtree(child, ignore_errors=True)
            else:
                child.unlink(missing_ok=True)

    return forget


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
