"""`analytic`: the analytic layer. Tune gains with NSGA-II on the farm (`start`, `resume`), take a
run's controller out of it (`export`), score an episode log (`evaluate`), evaluate fixed
candidates on the farm (`batch`), gather tuned controllers' episodes into a dataset (`dataset`),
learn the arm's dynamics from it (`learn`), run the paper's experiments (`experiment`), and watch
an episode as a video (`replay`)."""

import contextlib
import json
import shutil
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TypeVar

import click
from pydantic import ValidationError
from rich.console import Console
from rich.table import Table

from gainfarm.analytic.data.dataset import (
    DEFAULT_SPLIT,
    BadRerun,
    BadSplit,
    DuplicateEpisodes,
    NoEpisodes,
    RerunFailed,
    UnreadableRun,
    check_split,
    read_rerun,
)
from gainfarm.analytic.data.dataset import build as build_dataset
from gainfarm.analytic.data.learning import LearnError
from gainfarm.analytic.data.learning import learn as learn_model
from gainfarm.analytic.evaluators.batch import EVALUATIONS, batch_jobs, run_batch
from gainfarm.analytic.evaluators.evaluator import Evaluation, Evaluator
from gainfarm.analytic.evaluators.farm import DEFAULT_DEADLINE, FarmClient, FarmUnavailable
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.experiments import algorithms as algorithm_study
from gainfarm.analytic.experiments import base as experiments
from gainfarm.analytic.experiments import dataset_value
from gainfarm.analytic.experiments.base import Experiment
from gainfarm.analytic.tuning.checkpoint import CheckpointRefused
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import ALGORITHMS, OBJECTIVE_SCALINGS
from gainfarm.analytic.tuning.records import CONFIG_JSON, FRONT_FIELDS, read_front
from gainfarm.analytic.tuning.run import RunBusy, RunProgress, TuningRun
from gainfarm.analytic.tuning.tune import new_study_name
from gainfarm.analytic.view.dashboard import DASHBOARD_PORT, NoBokeh, Watch
from gainfarm.analytic.view.dashboard import run_forever as run_dashboard
from gainfarm.analytic.view.dashboard import serve as serve_dashboard
from gainfarm.analytic.view.export import FORMATS, BadMember, BadRun, describe_pick, picks
from gainfarm.analytic.view.export import controller as exported_controller
from gainfarm.analytic.view.export import render as render_controller
from gainfarm.analytic.view.progress import Display, RunDisplay
from gainfarm.analytic.view.replay import DEFAULT_FPS, DEFAULT_HEIGHT, DEFAULT_WIDTH, ReplayError
from gainfarm.analytic.view.replay import replay as replay_episode
from gainfarm.broker.status import query_status
from gainfarm.cli import interrupts, options
from gainfarm.cli.app import CliError, parse_numbers, program_group, run_app
from gainfarm.cli.scores import DIVERGED_TEXT, show_scores
from gainfarm.models.dynamics import KINDS, TARGETS, digest
from gainfarm.schemas.controller import BadGains, read_gains
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.files import write_atomically
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, read_episode
from gainfarm.schemas.objectives import balancing_weights, score
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.transport import open_session
from gainfarm.schemas.wire import BadMessage, describe

F = TypeVar("F", bound=Callable[..., object])
# Without a terminal, an experiment's progress is a plain line this often at most: its runs go
# on side by side, each a line per evaluation.
EXPERIMENT_LOG_SECONDS = 10.0


@program_group(__doc__)
def app() -> None:
    pass


def _bounds(field: str) -> click.IntRange:
    """The range RunConfig allows a field, as click's type: one rule, stated once."""
    limits = {
        name: getattr(rule, name)
        for rule in RunConfig.model_fields[field].metadata
        for name in ("ge", "le")
        if hasattr(rule, name)
    }
    return click.IntRange(min=limits.get("ge"), max=limits.get("le"))


def pop_option() -> Callable[[F], F]:
    return click.option(
        "--pop",
        type=_bounds("pop"),
        default=RunConfig.model_fields["pop"].default,
        show_default=True,
        help="population size",
    )


def termination_options(per_run: bool = False) -> Callable[[F], F]:
    """--generations and --evaluations (which exclude each other: RunConfig says so)."""
    when = "per run, instead of converging: " if per_run else ""
    return options.stack(
        click.option(
            "--generations", type=_bounds("generations"), help=f"{when}stop after N generations"
        ),
        click.option(
            "--evaluations", type=_bounds("evaluations"), help=f"{when}stop after N evaluations"
        ),
    )


# Where the farm is, the same for every command that uses one.
farm_options = options.stack(
    click.option("--connect", multiple=True, help="a running broker's Zenoh endpoint"),
    options.tls("a secure farm: directory with ca.pem and an analytic participant's pair"),
    click.option(
        "--as",
        "participant",
        help="with --tls: the analytic participant to be, if DIR holds several",
    ),
    click.option(
        "--local", is_flag=True, help="run the farm here: a broker in this process, workers"
    ),
    click.option(
        "--workers",
        type=click.IntRange(min=1, max=64),
        default=1,
        show_default=True,
        help="with a local farm: how many worker processes",
    ),
)


def _check_farm(
    connect: tuple[str, ...], local: bool, tls: Path | None, participant: str | None
) -> TlsIdentity | None:
    """The analytic identity to connect with, if the farm is secure."""
    if connect and local:
        raise CliError("--connect and --local exclude each other")
    if tls is not None and not connect:
        raise CliError("--tls needs --connect: a local farm runs on loopback, unsecured")
    if participant is not None and tls is None:
        raise CliError("--as needs --tls: a participant is a secure farm's identity")
    return options.identity(tls, "analytic", participant)


def _study_name(directory: Path, identity: TlsIdentity | None) -> str:
    """A new study name for work on `directory`; on a secure farm its owner's, as the access
    policy requires (docs/security.md)."""
    return new_study_name(directory, owner=identity.name if identity is not None else None)


@app.command(short_help="Score an episode from its MCAP log alone.")
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="print the scores as one JSON object")
def evaluate(log: Path, as_json: bool) -> None:
    """Score an episode from its MCAP log alone: f_acc, f_t and diagnostics."""
    if not log.is_file():
        raise CliError(f"{str(log)!r}: no such file")
    try:
        scores = score(read_episode(log))
    except NotAnEpisodeLog as error:
        raise CliError(str(error)) from None
    show_scores(scores, log, as_json)


@app.command(short_help="Render an episode log as a video.")
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="the MP4 to write")
@click.option(
    "--fps",
    type=click.IntRange(min=1, max=120),
    default=DEFAULT_FPS,
    show_default=True,
    help="frames per second of simulated time",
)
@click.option(
    "--width",
    type=click.IntRange(min=16, max=3840),
    default=DEFAULT_WIDTH,
    show_default=True,
    help="pixels, even",
)
@click.option(
    "--height",
    type=click.IntRange(min=16, max=2160),
    default=DEFAULT_HEIGHT,
    show_default=True,
    help="pixels, even",
)
def replay(log: Path, out: Path, fps: int, width: int, height: int) -> None:
    """Render an episode log as a video: the arm (MuJoCo, offscreen), the reference path (green)
    and the path the flange took (magenta)."""
    if not log.is_file():
        raise CliError(f"{str(log)!r}: no such file")
    try:
        frames = replay_episode(log, out, fps, width, height)
    except ReplayError as error:
        raise CliError(str(error)) from None
    click.echo(f"{out}: {frames} frames, {width}x{height} at {fps} fps")


@app.command(short_help="Watch runs and their farm live, in a web page.")
@click.argument("runs", nargs=-1, type=click.Path(path_type=Path))
@click.option(
    "--connect",
    multiple=True,
    help="the farm's broker, to show its workers, queue and throughput  [default: not shown]",
)
@options.tls("with --connect: the credentials of a secure farm")
@options.participant("analytic")
@click.option(
    "--port",
    type=click.IntRange(min=1, max=65535),
    default=DASHBOARD_PORT,
    show_default=True,
    help="the page's port, on 127.0.0.1",
)
def dashboard(
    runs: tuple[Path, ...],
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    port: int,
) -> None:
    """Watch tuning runs and their farm live, in a web page on this machine: each run's front
    and hypervolume curve, the farm's workers, queue and throughput. RUNS are run directories,
    or directories holding runs (an experiment's, runs/), whose new runs join the page as they
    start  [default: runs]. Until Ctrl-C."""
    for root in runs:
        if not root.is_dir():
            raise CliError(f"RUNS: {str(root)!r}: no such directory")
    if tls is not None and not connect:
        raise CliError("--tls needs --connect: the farm to watch")
    identity = options.identity(tls, "analytic", participant)
    session = None
    if connect:
        try:
            session = open_session("client", connect=connect, identity=identity)
        except (ValueError, ConnectionError) as error:
            raise CliError(f"--connect: {error}") from None
    try:
        with Watch(runs or (Path("runs"),), session, ", ".join(connect)) as watch:
            try:
                server = serve_dashboard(watch, port)
            except OSError as error:
                raise CliError(f"--port: cannot serve on {port}: {error.strerror}") from None
            except NoBokeh as error:
                raise CliError(str(error)) from None
            try:
                click.echo(f"dashboard at http://127.0.0.1:{port}/ (Ctrl-C stops it)")
                run_dashboard()
            finally:
                server.stop()
    finally:
        if session is not None:
            session.close()


@app.command(short_help="Evaluate given gains on the farm; keep every episode.")
@farm_options
@click.option(
    "--gains",
    "gains_file",
    type=click.Path(path_type=Path),
    help="the candidates: a controller from `analytic export`, a JSON list of "
    '{"kp": [7], "kd": [7]} objects, or a run\'s front.csv (every member)  '
    "[default: the default gains]",
)
@options.trajectory(multiple=True, help="repeat for several")
@options.duration()
@options.placement()
@options.model(help=None)
@options.plant()
@options.feedforward()
@click.option(
    "--run-dir",
    type=click.Path(path_type=Path),
    help="where episodes/ and evaluations.json go  [default: runs/batch-TIME]",
)
@click.option(
    "--deadline",
    type=click.FloatRange(min=1),
    default=DEFAULT_DEADLINE,
    show_default=True,
    help="seconds before an unanswered job is resubmitted",
)
@click.option("--json", "as_json", is_flag=True, help="print one JSON object per evaluation")
def batch(
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int,
    gains_file: Path | None,
    kinds: tuple[str, ...],
    duration: float,
    trajectory_seed: int,
    center: str,
    size: float,
    model: str,
    plant: str,
    feedforward: Path | None,
    run_dir: Path | None,
    deadline: float,
    as_json: bool,
) -> None:
    """Evaluate candidate gains on trajectories through the farm; keep and score every episode."""
    if not connect and not local:  # batch has no default farm
        raise CliError("say where the farm is: --connect ENDPOINT or --local")
    identity = _check_farm(connect, local, tls, participant)
    candidates = _candidates(gains_file)
    trajectories = options.trajectories(kinds, duration, trajectory_seed, center, size)
    _followable(trajectories)
    learned = options.feedforward_model(feedforward)
    models = {digest(learned[0]): learned[0]} if learned is not None else {}
    jobs = batch_jobs(candidates, trajectories, options.model_spec(plant, model), *models)
    run_dir = run_dir or Path("runs") / time.strftime("batch-%Y%m%d-%H%M%S")
    if (run_dir / EVALUATIONS).exists():
        raise CliError(f"--run-dir: {str(run_dir)!r} already holds a batch; choose another")
    forget = _claim(run_dir, "--run-dir")
    begun = False  # once the farm answers, the episodes are the batch's: kept, even if stopped
    try:
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise CliError(f"--run-dir: cannot create {str(run_dir)!r}: {error.strerror}") from None
        with _farm(connect, workers) as endpoints:
            try:
                farm = FarmClient(
                    endpoints,
                    _study_name(run_dir, identity),
                    run_dir,
                    deadline=deadline,
                    identity=identity,
                    models=models,
                )
            except (ValueError, ConnectionError) as error:
                raise CliError(_farm_problem(connect, error)) from None
            begun = True
            with farm, Display(enabled=not as_json) as display:
                done = 0

                def report(evaluation: Evaluation) -> None:
                    nonlocal done
                    interrupts.check()
                    done += 1
                    display.show(f"{done} of {len(jobs)} evaluated")
                    if done * 10 // len(jobs) != (done - 1) * 10 // len(jobs):  # every tenth
                        display.log(f"{done} of {len(jobs)} evaluated")
                    if as_json:
                        click.echo(json.dumps(_summary(evaluation)))

                try:
                    evaluations = run_batch(farm, jobs, run_dir, report)
                except BadMessage as error:
                    raise CliError(str(error)) from None
    except (CliError, KeyboardInterrupt):
        if not begun:
            forget()
        raise
    if not as_json:
        _print_evaluations(evaluations, run_dir)


@app.command(short_help="Tune the 14 PD gains on the farm (NSGA-II by default).")
@pop_option()
@options.trajectory(
    multiple=True,
    help="one: a specific controller; several (repeat): a generic one, objectives averaged "
    "(see --balance)",
)
@options.duration()
@options.placement()
@click.option(
    "--seed", type=click.IntRange(min=0), default=0, show_default=True, help="NSGA-II's seed"
)
@termination_options()
@options.model(help=None)
@options.plant()
@options.feedforward(
    help="add a learned inverse-dynamics model's torque for the reference to every episode's "
    "PD and tune the gains on top (a directory from `analytic learn`, or its model.npz)"
)
@farm_options
@click.option("--out", type=click.Path(path_type=Path), help="run directory  [default: runs/TIME]")
@click.option(
    "--keep",
    type=click.Choice(["all", "front"]),
    default="front",
    show_default=True,
    help="which episode logs to keep: the front's (the workers keep the logs and the front's "
    "are fetched from them), or all (each comes with its result and is kept: about 1.5 MB "
    "per 5 s episode, every evaluation's)",
)
@click.option(
    "--async",
    "asynchronous",
    is_flag=True,
    help="steady-state NSGA-II: a new candidate as soon as any result returns",
)
@click.option(
    "--algorithm",
    type=click.Choice(ALGORITHMS),
    default=RunConfig.model_fields["algorithm"].default,
    show_default=True,
    help="the optimiser: pymoo's NSGA-II, NSGA-III, SMS-EMOA, MOEA/D, AGE-MOEA-II, Optuna's "
    "TPE, or uniform random sampling (--async: nsga2 only)",
)
@click.option(
    "--objective-scaling",
    type=click.Choice(OBJECTIVE_SCALINGS),
    default=RunConfig.model_fields["objective_scaling"].default,
    show_default=True,
    help="what the optimiser is told: raw objectives, or log: as the hypervolume sees them "
    "(f_t on a log scale); the records stay raw",
)
@click.option(
    "--replicate/--no-replicate",
    default=True,
    show_default=True,
    help="on a farm of 2+ workers, validate the front: another worker reruns each member's "
    "episodes and the logs must agree bit for bit",
)
@click.option(
    "--balance/--no-balance",
    default=True,
    show_default=True,
    help="generic: weigh each trajectory's objectives so that all count alike at the default "
    "gains (simulated here first, one episode per trajectory), rather than the plain means, "
    "which the roughest trajectory would dominate",
)
def start(
    pop: int,
    kinds: tuple[str, ...],
    duration: float,
    trajectory_seed: int,
    center: str,
    size: float,
    seed: int,
    generations: int | None,
    evaluations: int | None,
    model: str,
    plant: str,
    feedforward: Path | None,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int,
    out: Path | None,
    keep: str,
    asynchronous: bool,
    algorithm: str,
    objective_scaling: str,
    replicate: bool,
    balance: bool,
) -> None:
    """Tune the 14 PD gains with NSGA-II (or --algorithm) on the farm: maximise accuracy,
    minimise torque steps.

    Stops after --generations, after --evaluations, or (by default) when the hypervolume has
    stopped growing. Ctrl-C stops cleanly; `analytic resume RUN` goes on.
    """
    identity = _check_farm(connect, local, tls, participant)
    trajectories = options.trajectories(kinds, duration, trajectory_seed, center, size)
    _followable(trajectories)
    learned = options.feedforward_model(feedforward)
    try:
        config = RunConfig(
            pop=pop,
            seed=seed,
            trajectories=trajectories,
            model=options.model_spec(plant, model),
            generations=generations,
            evaluations=evaluations,
            keep=keep,
            asynchronous=asynchronous,
            algorithm=algorithm,
            objective_scaling=objective_scaling,
            replicate=replicate,
            feedforward=digest(learned[0]) if learned is not None else None,
        )
    except ValidationError as error:
        raise CliError(_config_problem(error)) from None
    if balance and len(trajectories) > 1:
        config = _balanced(config, learned[0] if learned is not None else None)
    out = out or Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    if (out / CONFIG_JSON).exists():
        raise CliError(f"--out: {str(out)!r} already holds a run; resume it or choose another")
    forget = _claim(out, "--out")
    try:
        run = TuningRun.create(out, config, learned[0] if learned is not None else None)
    except FileExistsError as error:
        raise CliError(f"--out: {error}") from None
    except ValueError as error:  # an algorithm this installation cannot run (agemoea2: numba)
        raise CliError(f"--algorithm: {error}") from None
    except RunBusy as error:
        raise CliError(f"--out: {error}") from None
    except OSError as error:
        forget()
        raise CliError(
            f"--out: cannot write {str(error.filename or out)!r}: {error.strerror}"
        ) from None
    _tune(run, connect, workers, identity, forget)


@app.command(short_help="Continue a stopped run from its last checkpoint.")
@click.argument("run_dir", type=click.Path(path_type=Path))
@farm_options
def resume(
    run_dir: Path,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int,
) -> None:
    """Continue a stopped run from its last checkpoint."""
    identity = _check_farm(connect, local, tls, participant)
    if not (run_dir / CONFIG_JSON).is_file():
        raise CliError(f"{str(run_dir)!r} holds no run (no {CONFIG_JSON})")
    try:
        run = TuningRun.open(run_dir)
    except (RunBusy, CheckpointRefused) as error:
        raise CliError(str(error)) from None
    except OSError as error:  # its lock or run.json cannot be written, or a file read
        where = f"{str(error.filename)!r}: " if error.filename else ""
        raise CliError(
            f"{str(run_dir)!r}: cannot open the run: {where}{error.strerror or error}"
        ) from None
    except ValueError as error:
        raise CliError(f"{str(run_dir)!r}: unreadable run ({error})") from None
    if run.finished:
        run.close()
        raise CliError(f"{str(run_dir)!r} has finished: {run.state.stopped}")
    _tune(run, connect, workers, identity)


def _balanced(config: RunConfig, feedforward: bytes | None) -> RunConfig:
    """`config` with the generic objective balanced by the default gains' scores on each of its
    trajectories (schemas.objectives.balancing_weights), simulated in this process: a few
    episodes, before any farm is asked for."""
    from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator

    models = {config.feedforward: feedforward} if config.feedforward and feedforward else {}
    with InProcessEvaluator(models=models) as evaluator:
        evaluator.submit(
            {
                f"t{index}": EpisodeSpec(
                    gains=DEFAULT_GAINS,
                    trajectory=trajectory,
                    model=config.model,
                    feedforward=config.feedforward,
                )
                for index, trajectory in enumerate(config.trajectories)
            }
        )
        found = {evaluation.job_id: evaluation.scores for evaluation in evaluator.results()}
    reference = []
    for index, trajectory in enumerate(config.trajectories):
        scores = found[f"t{index}"]
        if scores is None or scores.diverged:
            raise CliError(
                f"--balance: the default gains do not finish the {trajectory.kind.value} "
                "trajectory, so there is nothing to balance by; give --no-balance"
            )
        reference.append((scores.f_acc, scores.f_t))
    return RunConfig.model_validate(
        config.model_dump() | {"objective_weights": balancing_weights(reference)}
    )


def _tune(
    run: TuningRun,
    connect: tuple[str, ...],
    workers: int,
    identity: TlsIdentity | None,
    forget: Callable[[], None] | None = None,
) -> None:
    """Run `run` (open, so holding its lock) on the farm, and close it. `forget`, for a run
    this command created: if the farm cannot be had (or Ctrl-C comes first), nothing has run,
    and it removes what the command made."""
    console = Console(stderr=True)
    begun = False
    try:
        with run, _farm(connect, workers) as endpoints:
            models = _run_models(run)
            try:
                farm = FarmClient(
                    endpoints,
                    _study_name(run.directory, identity),
                    run.directory,
                    identity=identity,
                    models=models,
                    # keep="front": the workers keep the logs, and the front's are fetched.
                    keep_logs=run.config.keep == "all",
                )
            except (ValueError, ConnectionError) as error:
                raise CliError(_farm_problem(connect, error)) from None
            begun = True
            with (
                farm,
                Display(console) as display,
                RunDisplay(display, lambda: _workers(farm), lambda: farm.waiting) as shown,
            ):

                def show(step: RunProgress) -> None:
                    interrupts.check()  # between evaluations: a Ctrl-C Python held back
                    shown.step(step)

                reason = run.run(farm, show)
    except CliError:
        if not begun and forget is not None:
            forget()
        raise
    except OSError as error:
        if isinstance(error, ConnectionError):  # the farm's: said where it happens
            raise
        raise _unwritable(error, f"go on with: analytic resume {run.directory}") from None
    except KeyboardInterrupt:
        if not begun and forget is not None:  # nothing ran: nothing to resume
            forget()
            interrupts.stop("analytic")
        generations = len(run.state.history)
        interrupts.stop(
            "analytic",
            f"stopped after {generations} generations; "
            f"continue with: analytic resume {run.directory}",
        )
    # Plain lines, whole however long: rich would wrap them at 80 columns off a terminal.
    click.echo(f"stopped: {reason}", err=True)
    ledger = run.replication
    if ledger.replicated:
        click.echo(
            f"front validated by replication: {ledger.replicated} episodes run again "
            f"({ledger.extra_evaluations} extra evaluations, {ledger.seconds:.1f} s), "
            f"{ledger.disagreements} disagreements, {ledger.undecided} undecided"
            + (
                f"; distrusted: {', '.join(sorted(ledger.dissenters))}" if ledger.dissenters else ""
            ),
            err=True,
        )
    click.echo(f"front, history, figures and report in {run.directory}/", err=True)
    chosen = picks(run.front())
    if chosen:  # last, what to do next; each line within 80 columns for a short run directory
        click.echo(f"controller to use: {describe_pick(chosen[0])}", err=True)
        click.echo(f"its gains: analytic export {run.directory}", err=True)


def _run_models(run: TuningRun) -> dict[str, bytes]:
    """The feed-forward model the run's episodes use, served to the workers."""
    try:
        return run.models()
    except ValueError as error:
        raise CliError(f"{str(run.directory)!r}: {error}") from None


def _workers(farm: FarmClient) -> int | None:
    """How many workers the farm has now; None if the broker does not answer within 2 s."""
    try:
        return query_status(farm.session, timeout=2.0).worker_count
    except Exception:  # no answer, a garbled one, or the session closed as the run ended
        return None


def _farm_problem(connect: tuple[str, ...], error: Exception) -> str:
    """Why the farm cannot be had, in one line naming the option that chose it."""
    return f"{'--connect' if connect else 'local farm'}: {error}"


def _claim(directory: Path, option: str) -> Callable[[], None]:
    """Check that `directory` (given as `option`) is new or empty, in one line if not; return
    what removes everything this command then puts there, for a start that fails before anything
    runs: the directory, with the parents it needed, or only what is in it if it was there."""
    if directory.exists() and not directory.is_dir():
        raise CliError(f"{option}: {str(directory)!r} is a file, not a directory")
    try:
        if directory.is_dir() and any(directory.iterdir()):
            raise CliError(
                f"{option}: {str(directory)!r} is not empty: choose a new or an empty directory"
            )
    except OSError as error:
        raise CliError(f"{option}: cannot read {str(directory)!r}: {error.strerror}") from None
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


@app.command(short_help="Gather tuned controllers' episodes into a dataset.")
@click.argument("run_dirs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="dataset directory")
@click.option(
    "--select",
    "selection",
    type=click.Choice(["front", "knee"]),
    default="front",
    show_default=True,
    help="every Pareto-front controller, or each run's knee",
)
@click.option(
    "--split",
    "split_text",
    metavar="TRAIN,VALIDATION,TEST",
    default=",".join(f"{value:g}" for value in DEFAULT_SPLIT),
    show_default=True,
    help="fractions of the trajectories in each part: the split is by trajectory, never by tick",
)
@click.option(
    "--split-seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="seed of the order the trajectories are dealt into the split in",
)
@click.option(
    "--rerun",
    "rerun_file",
    type=click.Path(path_type=Path),
    help="JSON list of trajectories (TrajectorySpec objects): run every selected controller once "
    "more on each, through the farm (a local one unless --connect), and add those episodes",
)
@farm_options
def dataset(
    run_dirs: tuple[Path, ...],
    out: Path,
    selection: str,
    split_text: str,
    split_seed: int,
    rerun_file: Path | None,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int,
) -> None:
    """Gather tuned controllers' episodes into a dataset: MCAP logs, Parquet tables, a card."""
    identity = _check_farm(connect, local, tls, participant)
    if rerun_file is None and (connect or local):  # saying so beats ignoring the option
        raise CliError("--connect and --local need --rerun: only a rerun runs episodes")
    for run_dir in run_dirs:
        if not (run_dir / CONFIG_JSON).is_file():
            raise CliError(f"{str(run_dir)!r} holds no run (no {CONFIG_JSON})")
    if out.exists():
        raise CliError(f"--out: {str(out)!r} already exists")
    try:
        split = check_split(parse_numbers("--split", split_text, 3))
        trajectories = read_rerun(rerun_file) if rerun_file is not None else []
    except BadSplit as error:
        raise CliError(f"--split: {error}") from None
    except BadRerun as error:
        raise CliError(f"--rerun: {error}") from None

    @contextlib.contextmanager
    def farm(directory: Path) -> Iterator[Evaluator]:
        """The rerun's farm, as `analytic batch` has it (started only once all is checked)."""
        with _farm(connect, workers) as endpoints:
            try:
                client = FarmClient(
                    endpoints, _study_name(directory, identity), directory, identity=identity
                )
            except (ValueError, ConnectionError) as error:
                raise CliError(_farm_problem(connect, error)) from None
            with client:
                yield client

    try:
        counts = build_dataset(
            list(run_dirs),
            out,
            selection,
            split=split,
            split_seed=split_seed,
            rerun_trajectories=trajectories,
            farm=farm,
        )
    except BadSplit as error:  # too few trajectories for the parts asked for
        raise CliError(f"--split: {error}") from None
    except BadRerun as error:  # a trajectory the robot cannot follow
        raise CliError(f"--rerun: {error}") from None
    except (NoEpisodes, UnreadableRun, DuplicateEpisodes, RerunFailed, BadMessage) as error:
        raise CliError(str(error)) from None
    except ConnectionError as error:  # the farm's, not the disk's
        raise CliError(_farm_problem(connect, error)) from None
    except OSError as error:
        raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror}") from None
    rerun = f", {counts['rerun']} of them rerun" if counts["rerun"] else ""
    click.echo(
        f"{out}: {counts['episodes']} episodes{rerun}, {counts['ticks']:,} ticks, "
        f"{counts['controllers']} controllers from {counts['runs']} runs, "
        f"{counts['trajectories']} trajectories ({counts['train']} train, "
        f"{counts['validation']} validation, {counts['test']} test)"
    )


@app.command(short_help="Learn the arm's dynamics from a dataset.")
@click.argument("dataset_dir", metavar="DATASET", type=click.Path(path_type=Path))
@click.option(
    "--out", type=click.Path(path_type=Path), required=True, help="model directory to write"
)
@click.option(
    "--target",
    type=click.Choice(TARGETS),
    default="inverse",
    show_default=True,
    help="inverse: torque u from (q, q̇, q̈); forward: q̈ from (q, q̇, u)",
)
@click.option(
    "--model",
    "kind",
    type=click.Choice(KINDS),
    default="residual",
    show_default=True,
    help="rigid: the rigid-body physics prior, untrained; linear: its parameters identified "
    "by least squares; mlp: a network; residual: the prior plus a network of what it misses",
)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
def learn(dataset_dir: Path, out: Path, target: str, kind: str, seed: int) -> None:
    """Learn the arm's dynamics from a dataset's train split; score on its test split.

    Writes OUT/model.npz (what --feedforward takes), scores.json (nMSE and RMSE per joint),
    report.md and prediction.png.
    """
    try:
        scores = learn_model(dataset_dir, out, target, kind, seed)
    except LearnError as error:
        raise CliError(str(error)) from None
    nmse = " ".join(f"{joint} {value:.3f}" for joint, value in scores["nmse"].items())
    click.echo(
        f"{out}: {kind} {target} model, test nMSE {scores['nmse_mean']:.4f} "
        f"(mean over A1-A6; mean predictor {scores['mean_predictor_nmse']:.2f}) · {nmse}"
    )


@app.command(short_help="Rerun the paper's experiments, or compare optimisers.")
@click.argument(
    "name",
    type=click.Choice(["popsize", "generic-vs-specific", "speed", "algorithms", "dataset-value"]),
)
@click.option(
    "--reps",
    type=click.IntRange(min=1),
    default=5,
    show_default=True,
    help="repetitions (seeds 0..reps-1)",
)
@click.option(
    "--sizes", default="10,20,30,50,80", show_default=True, help="popsize: population sizes"
)
@click.option(
    "--durations", default="3,4,5,6", show_default=True, help="speed: spiral durations, s"
)
@click.option(
    "--algorithms",
    "algorithm_names",
    default=",".join(ALGORITHMS),
    show_default=True,
    help="algorithms: the optimisers compared, comma-separated; the first is the reference "
    "every other is tested against. Each run gets --evaluations "
    f"(default {algorithm_study.DEFAULT_BUDGET})",
)
@click.option(
    "--objective-scaling",
    "scaling_names",
    default=RunConfig.model_fields["objective_scaling"].default,
    show_default=True,
    help="algorithms: what each optimiser is told, comma-separated: "
    + ", ".join(OBJECTIVE_SCALINGS),
)
@click.option(
    "--test-trajectories",
    type=int,
    default=dataset_value.DEFAULT_TEST_TRAJECTORIES,
    show_default=True,
    help="dataset-value: held-out test trajectories (fourier and random-kind, seeds 1000..)",
)
@click.option(
    "--ticks",
    type=int,
    help="dataset-value: training rows per condition and repetition  "
    "[default: the smallest pool's]",
)
@pop_option()
@click.option(
    "--duration",
    type=float,
    help="trajectory duration, s (popsize, generic-vs-specific, algorithms, dataset-value)  "
    f"[default: 5; dataset-value: {dataset_value.DEFAULT_DURATION:g}]",
)
@options.plant()
@termination_options(per_run=True)
@farm_options
@click.option(
    "--parallel-runs",
    type=click.IntRange(min=1),
    help="tuning runs (with their cross-evaluations) at once, each its own study on the farm  "
    "[default: all of the experiment's]",
)
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    required=True,
    help="experiment directory (an existing one is resumed)",
)
def experiment(
    name: str,
    reps: int,
    sizes: str,
    durations: str,
    algorithm_names: str,
    scaling_names: str,
    test_trajectories: int,
    ticks: int | None,
    pop: int,
    duration: float | None,
    plant: str,
    generations: int | None,
    evaluations: int | None,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int,
    parallel_runs: int | None,
    out: Path,
) -> None:
    """Rerun one of the paper's experiments: popsize, generic-vs-specific or speed; compare the
    optimisers the paper left open: algorithms; or test the paper's claim that tuned
    controllers' data teach the dynamics better: dataset-value.

    algorithms: each of --algorithms told each --objective-scaling, --reps runs each on the
    spiral of --duration, every run on the same budget of --evaluations (default 600), against
    the first algorithm listed, with the classical per-joint PD rule as a baseline without a
    genetic algorithm; and a check of the convergence rule the other studies stop by.
    """
    identity = _check_farm(connect, local, tls, participant)
    chosen: tuple[list[str], list[str]] = ([], [])
    if name == "algorithms":
        if generations is not None:
            raise CliError(
                "--generations: the algorithms study compares on a budget of evaluations "
                f"(--evaluations, default {algorithm_study.DEFAULT_BUDGET}), not of generations"
            )
        evaluations = evaluations or algorithm_study.DEFAULT_BUDGET
        chosen = (
            _names("--algorithms", algorithm_names, ALGORITHMS, "algorithm"),
            _names("--objective-scaling", scaling_names, OBJECTIVE_SCALINGS, "objective scaling"),
        )
        try:
            algorithm_study.check_runnable(chosen[0], pop)
        except ValueError as error:  # an algorithm this installation cannot run
            raise CliError(f"--algorithms: {error}") from None
    if duration is None:
        duration = dataset_value.DEFAULT_DURATION if name == "dataset-value" else 5.0
    if test_trajectories < 1:
        raise CliError(f"--test-trajectories: {test_trajectories} is not at least 1")
    if ticks is not None and ticks < 10:
        # Fewer rows cannot hold a validation part and a training part worth the name.
        raise CliError(f"--ticks: {ticks} is not at least 10")

    size_list = [int(v) for v in parse_numbers("--sizes", sizes)]
    duration_list = list(parse_numbers("--durations", durations))
    try:
        base = RunConfig(
            pop=pop,
            trajectories=(TrajectorySpec(duration=duration),),
            model=PLANTS[plant],
            generations=generations,
            evaluations=evaluations,
            keep="front",
        )
        for size in size_list:
            RunConfig(pop=size)
        if name == "speed":
            used = [TrajectorySpec(duration=value) for value in duration_list]
        elif name == "dataset-value":
            used = [
                *dataset_value.training_trajectories(duration),
                *dataset_value.test_trajectories(duration, test_trajectories),
            ]
        else:
            kinds = experiments.ALL_KINDS if name == "generic-vs-specific" else ["spiral"]
            used = [TrajectorySpec(kind=kind, duration=duration) for kind in kinds]
    except ValidationError as error:
        raise CliError(_config_problem(error)) from None
    if ticks is not None and ticks > dataset_value.smallest_pool(duration):
        raise CliError(
            f"--ticks: {ticks} is more than the smallest pool holds at {duration:g} s "
            f"({dataset_value.smallest_pool(duration)} rows: three episodes)"
        )
    _followable(used, "--durations" if name == "speed" else "--duration")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise CliError(f"--out: cannot create {str(out)!r}: {error.strerror}") from None
    console = Console(stderr=True)

    def progress(text: str) -> None:
        """A run's step (called from the runs' threads): the place a Ctrl-C stops them."""
        interrupts.check()
        display.show(text)
        display.every(text, EXPERIMENT_LOG_SECONDS)

    try:
        with _farm(connect, workers) as endpoints, Display(console) as display:
            display.show(name)
            experiment = Experiment(
                out,
                # The experiment's own study names are neither unique nor short enough.
                # Experiments keep their fronts' logs alone: fetched from the workers.
                lambda _name, directory: FarmClient(
                    endpoints,
                    _study_name(directory, identity),
                    directory,
                    identity=identity,
                    keep_logs=False,
                ),
                progress,
                parallel=parallel_runs,
            )
            try:
                if name == "popsize":
                    experiments.popsize(experiment, base, size_list, reps)
                elif name == "generic-vs-specific":
                    experiments.generic_vs_specific(experiment, base, reps)
                elif name == "algorithms":
                    algorithm_study.algorithms(experiment, base, *chosen, reps)
                elif name == "dataset-value":
                    dataset_value.dataset_value(experiment, base, reps, test_trajectories, ticks)
                else:
                    experiments.speed(experiment, base, duration_list, reps)
            except (ValueError, RunBusy) as error:
                raise CliError(str(error)) from None
    except OSError as error:
        if isinstance(error, ConnectionError):
            raise CliError(_farm_problem(connect, error)) from None
        raise _unwritable(error, "run the same command again to go on") from None
    except KeyboardInterrupt:
        interrupts.stop("analytic", "stopped; run the same command again to go on")
    click.echo(f"{name}: report, figures and results.csv in {out}/", err=True)


def _names(option: str, text: str, allowed: tuple[str, ...], what: str) -> list[str]:
    """Comma-separated names from an option's value, each one of `allowed`, none twice."""
    names = [part.strip() for part in text.split(",")]
    try:
        algorithm_study.check_names(names, allowed, what)
    except ValueError as error:
        raise CliError(f"{option}: {error}") from None
    return names


def _unwritable(error: OSError, then: str) -> CliError:
    """A file of a run that could not be written (disk full, read-only, no permission), in one
    line: the files are each whole or absent and the checkpoint is the last good one, so once
    the cause is gone the run goes on as `then` says."""
    where = f" {str(error.filename)!r}" if error.filename else ""
    return CliError(f"cannot write{where}: {error.strerror or error}; once it can, {then}")


def _followable(trajectories: Iterable[TrajectorySpec], option: str = "--duration") -> None:
    """Refuse, in one line, a trajectory the iiwa cannot follow (out of reach, or too fast for
    its limits) before any job is sent: every episode of it would fail."""
    from gainfarm.worker.ik import UnreachablePath  # MuJoCo loads only when a command needs it
    from gainfarm.worker.reference import InfeasibleReference, reference_for

    for trajectory in trajectories:
        try:
            reference_for(trajectory)
        except InfeasibleReference as error:
            raise CliError(f"{option}: {error}") from None
        except UnreachablePath as error:
            raise CliError(f"--center/--size: {error}") from None


def _config_problem(error: ValidationError) -> str:
    """A RunConfig's complaint in one line; its rule on the termination names the options."""
    text = describe(error)
    return text.replace("generations and evaluations", "--generations and --evaluations")


@contextlib.contextmanager
def _farm(connect: tuple[str, ...], workers: int) -> Iterator[list[str]]:
    """The endpoints to use: the given broker's, or else a local farm's (a local farm that
    cannot start is one line; what goes wrong later in the block is not relabelled)."""
    if connect:
        yield list(connect)
        return
    try:
        with local_farm(workers) as endpoint:
            yield [endpoint]
    except (ValueError, ConnectionError, FarmUnavailable) as error:
        raise CliError(f"local farm: {error}") from None


def _candidates(path: Path | None) -> list[PDGains]:
    """--gains' candidates: an exported controller or a JSON list of gains
    (schemas.controller.read_gains), or every member of a run's front.csv."""
    if path is None:
        return [DEFAULT_GAINS]
    try:
        raw = path.read_bytes()
    except OSError as error:
        raise CliError(f"--gains: cannot read {str(path)!r}: {error.strerror}") from None
    if raw.startswith(FRONT_FIELDS[0].encode() + b","):  # a CSV whose header is front.csv's
        try:
            front = read_front(path)
        except ValueError as error:
            raise CliError(f"--gains: {str(path)!r}: {error}") from None
        if not front:
            raise CliError(f"--gains: {str(path)!r} is a front.csv with no members")
        return [member.gains for member in front]
    try:
        return read_gains(raw)
    except BadGains as error:
        raise CliError(f"--gains: {str(path)!r}: {error}") from None


def _summary(evaluation: Evaluation) -> dict[str, object]:
    scores = evaluation.scores.model_dump() if evaluation.scores else {}
    episode = str(evaluation.log) if evaluation.log else None
    return {
        "job_id": evaluation.job_id,
        "status": evaluation.status.value,
        **scores,
        "reason": evaluation.reason,
        "episode": episode,
    }


def _print_evaluations(evaluations: list[Evaluation], run_dir: Path) -> None:
    table = Table(
        "job",
        "status",
        "f_acc (mm)",
        "f_t ((N·m)²)",
        "worker",
        title=f"{run_dir}/{EVALUATIONS}",
        title_justify="left",
    )
    for evaluation in evaluations:
        scores = evaluation.scores
        table.add_row(
            evaluation.job_id,
            evaluation.status
            if not evaluation.reason
            else f"{evaluation.status}: {evaluation.reason}",
            f"{scores.f_acc * 1000:.3f}" if scores else "",
            f"{scores.f_t:.4g}" if scores else "",
            evaluation.worker,
        )
    Console().print(table)
    if any(evaluation.scores and evaluation.scores.diverged for evaluation in evaluations):
        Console().print(DIVERGED_TEXT, highlight=False)


# --- analytic export: a run's controller, out of the run ------------------------------------------


@app.command(short_help="Write a run's controller (the knee by default) to use.")
@click.argument("run_dir", metavar="RUN", type=click.Path(path_type=Path))
@click.option(
    "--member",
    default="knee",
    show_default=True,
    metavar="knee|accurate|smooth|N",
    help="which front member: the knee (the best compromise), the most accurate, the "
    "smoothest, or row N of front.csv (the report's #)",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(FORMATS),
    default="json",
    show_default=True,
    help="json: what `analytic batch --gains` and `worker episode --gains` read; yaml: the "
    "same document; ros2_control: a controller_manager parameter file running the gains as a "
    "PD on the effort interface",
)
@click.option(
    "--out", type=click.Path(path_type=Path), help="file to write  [default: standard output]"
)
def export(run_dir: Path, member: str, fmt: str, out: Path | None) -> None:
    """Write a run's controller: one front member's gains, with its joints, units, scores and
    the run it came from."""
    try:
        chosen = exported_controller(run_dir, member)
    except BadRun as error:
        raise CliError(str(error)) from None
    except BadMember as error:
        raise CliError(f"--member: {error}") from None
    content = render_controller(chosen, fmt)
    if out is None:
        click.echo(content.decode(), nl=False)
        return
    if not out.parent.is_dir():
        raise CliError(f"--out: directory {str(out.parent)!r} does not exist")
    try:
        write_atomically(out, content)
    except OSError as error:
        raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror or error}") from None
    click.echo(
        f"{out}: {chosen.member.selected} of {run_dir} (front.csv row {chosen.member.row}: "
        f"{chosen.member.f_acc * 1000:.3f} mm, f_t {chosen.member.f_t:.4g} (N·m)²), {fmt}",
        err=True,
    )


def main() -> None:
    run_app(app, "analytic")
