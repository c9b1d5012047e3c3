"""What the `analytic` commands that run episodes share once their options are checked: the farm
(a broker's, or a local one), the output directory claimed, a tuning run with its progress on
the terminal and what it says as it ends. Heavy (MuJoCo, Zenoh, pymoo, rich at the top): a
command imports it once every option is checked (work/common.py)."""

import contextlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import click
from rich.console import Console

from gainfarm import plugins
from gainfarm.analytic.commands.shared import farm_problem, start_option, unwritable
from gainfarm.analytic.commands.work.common import make_config
from gainfarm.analytic.compose import (
    STAGES,
    CannotStart,
    FarmOptions,
    TuningInterrupted,
    Watch,
    check_followable,
    claim,
    complete,
    make_run,
    new_directory,
    new_study_name,
    tune_run,
)
from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.evaluators.farm import FarmUnavailable
from gainfarm.analytic.evaluators.local import LocalFarm
from gainfarm.analytic.tuning.check import CheckPlan, advice_of, read_check
from gainfarm.analytic.tuning.checkpoint import CheckpointRefused
from gainfarm.analytic.tuning.records import REPORT_MD
from gainfarm.analytic.tuning.run import RunBusy, RunProgress, TuningRun
from gainfarm.analytic.view.export import describe_pick, picks
from gainfarm.analytic.view.progress import Display, RunDisplay
from gainfarm.analytic.view.reports import stopped_text
from gainfarm.broker.status import query_status
from gainfarm.cli import interrupts
from gainfarm.cli.app import CliError
from gainfarm.cli.words import counted
from gainfarm.models.dynamics import digest
from gainfarm.schemas.limits import tally
from gainfarm.schemas.robot import DEFAULT_ROBOT
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.schemas.wire import one_line


def study_name(directory: Path, identity: TlsIdentity | None) -> str:
    """A new study name for work on `directory`; on a secure farm its owner's, as the access
    policy requires (docs/security.md)."""
    return new_study_name(directory, owner=identity.name if identity is not None else None)


@contextlib.contextmanager
def farm(
    connect: tuple[str, ...], workers: int | None, robot: str | None = None
) -> Iterator[list[str]]:
    """The endpoints to use: the given broker's, or else a local farm's, of `robot` if known
    (a local farm that cannot start is one line; what goes wrong later in the block is not
    relabelled)."""
    with own_farm(connect, workers, robot) as (endpoints, _):
        yield endpoints


@contextlib.contextmanager
def own_farm(
    connect: tuple[str, ...], workers: int | None, robot: str | None = None
) -> Iterator[tuple[list[str], frozenset[str] | None]]:
    """As `farm`, with the names of a local farm's workers (None with --connect): the only
    workers whose results a client of it takes (FarmClient's `own_workers`)."""
    if connect:
        yield list(connect), None
        return
    with contextlib.ExitStack() as stack:
        try:
            local = stack.enter_context(LocalFarm(workers, robot=robot))
            endpoint = local.ready()
        except (ValueError, ConnectionError, FarmUnavailable) as error:
            raise CliError(f"local farm: {error}") from None
        yield [endpoint], frozenset(local.names)


@contextlib.contextmanager
def claimed(directory: Path, option: str) -> Iterator[Callable[[], None]]:
    """`directory`, new or empty, made for a command's output; if the block fails (or is
    interrupted) before it calls the `keep` it is given, everything put there is removed again,
    so that a refused or stopped command leaves nothing. One line naming `option` if it cannot
    be had."""
    try:
        forget = claim(directory)
    except CannotStart as error:
        raise CliError(f"{option}: {error}") from None
    kept = False

    def keep() -> None:
        nonlocal kept
        kept = True

    try:
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise CliError(
                f"{option}: cannot create {str(directory)!r}: {error.strerror}"
            ) from None
        yield keep
    except (CliError, KeyboardInterrupt):
        if not kept:
            forget()
        raise


def followable(
    trajectories: Iterable[TrajectorySpec], option: str = "--duration", robot: str = DEFAULT_ROBOT
) -> None:
    """Refuse, in one line, a trajectory `robot` cannot follow (out of reach, or too fast for
    its limits) before any job is sent: every episode of it would fail."""
    try:
        check_followable(trajectories, robot)
    except CannotStart as error:
        raise CliError(f"{start_option(error.part, option)}: {error}") from None


def start_run(fields: dict, out: Path | None, model_file: bytes | None, where: FarmOptions) -> None:
    """`analytic start`'s run, its options checked: the RunConfig of `fields` (with the SHA-256
    of `model_file`, the --feedforward model, if given), made in `out` (runs/TIME by default)
    as `tune` makes it and run on `where` with its progress shown."""
    if model_file is not None:
        fields = fields | {"feedforward": digest(model_file)}
    config = make_config(fields)
    out = out or new_directory()

    def go(watch: Watch, on_check: Callable[[CheckPlan], None]) -> TuningRun:
        run, forget = make_run(config, out, model_file)
        tune_run(run, where, watch=watch, on_check=on_check, forget=forget)
        return run

    try:
        run_with_progress(go, out, where.connect)
    except CannotStart as error:
        also = "; give --no-balance" if error.part == "balance" else ""
        raise CliError(f"{start_option(error.part)}: {error}{also}") from None
    except RunBusy as error:
        raise CliError(f"--out: {error}") from None


def resume_run(run_dir: Path, where: FarmOptions) -> None:
    """`analytic resume`'s run, its options checked: the run in `run_dir` opened and run on
    `where` with its progress shown; one line if it cannot be opened or has finished."""
    try:
        run = TuningRun.open(run_dir)
    except (RunBusy, CheckpointRefused) as error:
        raise CliError(str(error)) from None
    except OSError as error:  # its lock or run.json cannot be written, or a file read
        at = f"{str(error.filename)!r}: " if error.filename else ""
        raise CliError(
            f"{str(run_dir)!r}: cannot open the run: {at}{error.strerror or error}"
        ) from None
    except ValueError as error:
        raise CliError(f"{str(run_dir)!r}: unreadable run ({one_line(error)})") from None
    if complete(run):  # else what a Ctrl-C after the evolution left is done now
        run.close()
        raise CliError(f"{str(run_dir)!r} has finished: {run.state.stopped}")

    def go(watch: Watch, on_check: Callable[[CheckPlan], None]) -> TuningRun:
        tune_run(run, where, watch=watch, on_check=on_check)
        return run

    try:
        run_with_progress(go, run_dir, where.connect)
    except CannotStart as error:  # its feed-forward model file is missing, or another
        raise CliError(str(error)) from None


def run_with_progress(
    go: Callable[[Watch, Callable[[CheckPlan], None]], TuningRun],
    directory: Path,
    connect: tuple[str, ...],
) -> None:
    """Tune as `go` does (`tune`, or `tune_run` of an opened run), given what shows its progress
    (a live line, or a plain line a generation) and stops it at a Ctrl-C, and what says the
    held-out check as it starts; then say why it stopped, what replication found, which
    controller to use and how it did held out. `directory` is the run's."""
    console = Console(stderr=True)

    @contextlib.contextmanager
    def watch(farm: Evaluator) -> Iterator[Callable[[RunProgress], None]]:
        with (
            Display(console, hushed=interrupts.INTERRUPTED.is_set) as display,
            RunDisplay(
                display, lambda: _workers(farm), lambda: getattr(farm, "waiting", None)
            ) as shown,
        ):

            def step(progress: RunProgress) -> None:
                interrupts.check()  # between evaluations: a Ctrl-C Python held back
                shown.step(progress)

            yield step

    def checking(plan: CheckPlan) -> None:
        # Seconds to minutes with no other line: say what runs. Through the live line's console,
        # which prints it above that line (a plain write would land on its end).
        # start-up: run_report brings matplotlib (the run loads it while its first results come
        # in, compose._loading_figures), so it is loaded here, not before the run.
        from gainfarm.analytic.view.run_report import check_start_line

        if not interrupts.INTERRUPTED.is_set():
            console.print(check_start_line(plan), markup=False, highlight=False, soft_wrap=True)

    try:
        run = go(watch, checking)
    except FarmUnavailable as error:
        raise CliError(farm_problem(connect, error)) from None
    except plugins.PluginError as error:  # a worker (or this process) lacks a plug-in
        raise CliError(f"{error}, on every worker; then: analytic resume {directory}") from None
    except TuningInterrupted as stopped:
        if stopped.run is None:  # nothing ran: nothing to resume
            interrupts.stop("analytic")
        interrupts.stop("analytic", interrupted_text(stopped.run, stopped.stage))
    except OSError as error:
        if isinstance(error, ConnectionError):  # the farm's: said where it happens
            raise
        raise unwritable(error, f"go on with: analytic resume {directory}") from None
    # Plain lines, whole however long: rich would wrap them at 80 columns off a terminal.
    infeasible, _ = tally(run.config.limits, run.state.measured)
    if infeasible or not run.front():  # which limits: report.md's "Safety limits"
        front = "" if run.front() else "; none kept to them all: the front is empty"
        click.echo(
            f"limits: {infeasible} of {counted(len(run.state.measured), 'candidate')} broke "
            f"one{front}",
            err=True,
        )
    click.echo(stopped_text(run.state.stopped or ""), err=True)
    ledger = run.replication
    defaults = ledger.baseline + ledger.held_out
    if ledger.refereed or ledger.spot_checked or ledger.failures_checked or defaults:
        rate = f" (rate {run.state.spot_rate:.3g})" if run.state.spot_rate else ""
        click.echo(
            f"validation: {counted(ledger.refereed, 'front episode')}, "
            f"{counted(ledger.spot_checked, 'spot check')}{rate}, "
            f"{counted(ledger.failures_checked, 'claimed failure')} and {defaults} baseline and "
            f"held-out check episodes rerun here in "
            f"{ledger.seconds:.1f} s, {ledger.disagreements} disagreed"
            + (f", {ledger.unsettled} could not be rerun (failed)" if ledger.unsettled else "")
            + (f"; distrusted: {', '.join(sorted(ledger.dissenters))}" if ledger.dissenters else "")
            + (
                f"; the evolution started again without their results ({run.state.rewinds}x)"
                if run.state.rewinds
                else ""
            ),
            err=True,
        )
    click.echo(f"front, history, figures and report in {run.directory}/", err=True)
    record = read_check(run.directory)
    chosen = picks(run.front(), run.baseline(), advice_of(record))
    if not chosen:
        return
    # Last, what to do next, as report.md's first line says; each line within 80 columns for a
    # short run directory.
    first = chosen[0]
    # How the controller named fared on the held-out plants, beside its name: "use row 14" is
    # not said without "12 of 37 held-out plants broke a limit".
    # start-up: matplotlib, as in `checking`; loaded by now (the run drew its figures)
    from gainfarm.analytic.view.run_report import held_out_lines

    # Keeping the default gains on the check's advice: theirs are the figures to quote.
    kept = first.name == "closest" and advice_of(record) is not None
    held_out = held_out_lines(record, None if kept else first.row) if record else []
    if first.name == "recommended":
        click.echo(f"controller to use: {describe_pick(first)}", err=True)
        for line in held_out:
            click.echo(line, err=True)
        click.echo(f"its gains: analytic export {run.directory}", err=True)
        return
    if first.name == "closest" and advice_of(record) is not None:
        click.echo("controller to use: the default gains; no member held against them", err=True)
        click.echo(f"closest on the check: {describe_pick(first)}", err=True)
    elif first.name == "closest":
        click.echo("controller to use: none, no member beats the default gains", err=True)
        click.echo(f"closest to them: {describe_pick(first)}", err=True)
    else:  # the run has no baseline.json
        click.echo("controller to use: unknown, the default gains were not scored", err=True)
        click.echo(f"the knee: {describe_pick(first)}", err=True)
    for line in held_out:
        click.echo(line, err=True)
    click.echo(f"what to do: {run.directory}/{REPORT_MD}", err=True)


def interrupted_text(run: TuningRun, stage: str) -> str:
    """What a Ctrl-C leaves, in one line: the generations saved (a resume starts after them,
    which can be fewer than were shown: the records are written at most every RECORD_SECONDS),
    or, after the evolution, what is left to finish."""
    resume = f"analytic resume {run.directory}"
    saved, reached = run.saved_generations, len(run.state.history)
    if stage != "evolution":
        return (
            f"stopped during {STAGES[stage]}, after the evolution's "
            f"{counted(saved, 'generation')}; finish with: {resume}"
        )
    if saved == 0:
        return f"stopped before its first generation was saved; continue with: {resume}"
    if saved == reached:
        return f"stopped after {counted(saved, 'generation')}; continue with: {resume}"
    return (
        f"stopped after {counted(reached, 'generation')}, saved at generation {saved}; "
        f"continue with: {resume} (it runs generation {saved + 1} on)"
    )


def _workers(farm: Evaluator) -> int | None:
    """How many workers the farm has now; None if the broker does not answer within 2 s."""
    try:
        return query_status(farm.session, timeout=2.0).worker_count  # type: ignore[attr-defined]
    except Exception:  # no answer, a garbled one, or the session closed as the run ended
        return None
