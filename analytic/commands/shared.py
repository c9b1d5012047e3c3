"""What several `analytic` commands share: the options of a run and of the farm, and the one-line
errors that name them. Light: click and the run's defaults at the top, the rest where used."""

import contextlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import click

from gainfarm.analytic.tuning import defaults
from gainfarm.cli import options
from gainfarm.cli.app import CliError
from gainfarm.cli.words import counted

if TYPE_CHECKING:
    from pydantic import ValidationError

    from gainfarm.analytic.compose import Watch
    from gainfarm.analytic.evaluators.evaluator import Evaluator
    from gainfarm.analytic.tuning.check import CheckPlan
    from gainfarm.analytic.tuning.run import RunProgress, TuningRun
    from gainfarm.schemas.plant_file import PlantFile
    from gainfarm.schemas.robot import ModelSpec
    from gainfarm.schemas.security import TlsIdentity
    from gainfarm.schemas.trajectory import TrajectorySpec

F = TypeVar("F", bound=Callable[..., object])


def pop_option() -> Callable[[F], F]:
    return click.option(
        "--pop",
        type=click.IntRange(min=defaults.POP_MIN, max=defaults.POP_MAX),
        default=defaults.POP,
        show_default=True,
        help="population size",
    )


def termination_options(per_run: bool = False) -> Callable[[F], F]:
    """--generations and --evaluations (which exclude each other: RunConfig says so)."""
    when = "per run, instead of converging: " if per_run else ""
    return options.stack(
        click.option(
            "--generations",
            type=click.IntRange(min=defaults.GENERATIONS_MIN),
            help=f"{when}stop after N generations",
        ),
        click.option(
            "--evaluations",
            type=click.IntRange(min=defaults.EVALUATIONS_MIN),
            help=f"{when}stop after N evaluations",
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
        "--local", is_flag=True, help="run the farm here: a broker process and worker processes"
    ),
    click.option(
        "--workers",
        type=click.IntRange(min=1, max=64),
        help="with a local farm: how many worker processes (they share the cores: each steps "
        "its episodes on cores / N threads)  [default: one per core]",
    ),
)


def robustness() -> Callable[[F], F]:
    """--plants K, --aggregate and --uncertainty FILE: robust tuning over plant variants."""
    return options.stack(
        click.option(
            "--plants",
            type=click.IntRange(0, 64),
            default=defaults.PLANTS,
            show_default=True,
            metavar="K",
            help="robust tuning: score every candidate on the nominal plant and K variants, the "
            "designed corners first (the heavy and the light arm), then random "
            "draws from the uncertainty ranges, the same for every candidate; constraints hold "
            "on every one (0: the nominal plant alone)",
        ),
        click.option(
            "--aggregate",
            type=click.Choice(("mean", "worst", "cvar")),
            default=defaults.AGGREGATE,
            show_default=True,
            help="each trajectory's objectives over its plants, each objective apart: the mean, "
            "the worst (a bound on every plant), or the mean of the worst quarter",
        ),
        click.option(
            "--check-plants",
            type=click.IntRange(0, 256),
            default=64,
            show_default=True,
            metavar="M",
            help="once the run ends, run the controllers it names and the default gains on M "
            "held-out plants drawn from the same ranges (check.json; 0: no check)",
        ),
        uncertainty(
            "the ranges the variants are drawn from, a TOML file in the form of the shipped "
            "models/uncertainty.toml (its defaults, each with its source)"
        ),
    )


bag_topics = options.stack(
    click.option(
        "--joint-states",
        default="/joint_states",
        show_default=True,
        help="a bag's sensor_msgs/JointState topic of the measured angles, velocities and torques",
    ),
    click.option(
        "--commands",
        default="/joint_commands",
        show_default=True,
        help="a bag's JointState topic whose effort is the torque the controller sent",
    ),
    click.option(
        "--motor-states",
        default="/motor_states",
        show_default=True,
        help="a bag's JointState topic of the motor angles, if the arm logs them (the joint "
        "stiffness needs them)",
    ),
)


def uncertainty(help: str) -> Callable[[F], F]:
    """--uncertainty FILE, the plant ranges (parameter `uncertainty_file`)."""
    return click.option(
        "--uncertainty",
        "uncertainty_file",
        type=click.Path(path_type=Path),
        metavar="FILE",
        help=help,
    )


def _uncertainty(plant_file: "PlantFile", nominal: "ModelSpec") -> dict:
    """The plant file's ranges for `nominal`: once its calibrated payload is the told load (no
    --payload given: options.with_load), that load's error instead of the untold payload's."""
    told = plant_file.told()
    if (nominal.load, nominal.payload) == (told.plant.load, told.plant.payload):
        return told.uncertainty
    return plant_file.uncertainty


def plants_from(
    count: int,
    path: Path | None,
    nominal: "ModelSpec",
    seed: int,
    held_out: bool = False,
    plant: str | None = None,
    designed: bool = False,
) -> "tuple[ModelSpec, ...]":
    """--plants K variants of `nominal` (`held_out`: --check-plants M of them, on the seed's
    other stream; `designed`: robust tuning's, the corners first), drawn from --uncertainty
    FILE's ranges, else from those of the plant file --plant names (a calibrated twin's), else
    the shipped ones; or one line naming the option."""
    from gainfarm.analytic.tuning.plants import (
        HELD_OUT,
        TUNING,
        BadUncertainty,
        design,
        ranges,
        ranges_of,
        variants,
    )
    from gainfarm.schemas.robot import PLANTS
    from gainfarm.schemas.wire import one_line

    stream = HELD_OUT if held_out else TUNING

    def drawn(table: "dict | None") -> "tuple[ModelSpec, ...]":
        if designed:
            return design(nominal, count, seed, table)
        return variants(nominal, count, seed, table, stream)

    if path is None:
        table = None
        if plant is not None and plant not in PLANTS:
            try:
                table = ranges_of(_uncertainty(options.plant_file(plant), nominal)) or None
            except BadUncertainty as error:
                raise CliError(f"--plant: {plant!r}: uncertainty: {error}") from None
        try:
            return drawn(table)
        except ValueError as error:
            raise CliError(
                f"--plant: {plant!r}: a variant is no plant ({one_line(error)})"
            ) from None
    from gainfarm.schemas.documents import BadDocument, read_bounded

    try:
        text = read_bounded(path).decode()
    except OSError as error:
        raise CliError(f"--uncertainty: cannot read {str(path)!r}: {error.strerror}") from None
    except BadDocument as error:
        raise CliError(f"--uncertainty: {str(path)!r}: {error}") from None
    except UnicodeDecodeError:
        raise CliError(f"--uncertainty: {str(path)!r} is not text") from None
    try:
        table = ranges(text)
    except BadUncertainty as error:
        raise CliError(f"--uncertainty: {str(path)!r}: {error}") from None
    if not table:
        # An empty file (or one with no table) would draw every variant equal to the nominal
        # plant: robust tuning that is not, without a word.
        raise CliError(
            f"--uncertainty: {str(path)!r} holds no ranges (a table per parameter, as in the "
            "shipped models/uncertainty.toml)"
        )
    try:
        return drawn(table)
    except ValueError as error:  # a range that takes the plant out of what it may be
        raise CliError(
            f"--uncertainty: {str(path)!r}: a variant is no plant ({one_line(error)})"
        ) from None


def check_farm(
    connect: tuple[str, ...], local: bool, tls: Path | None, participant: str | None
) -> "TlsIdentity | None":
    """The analytic identity to connect with, if the farm is secure."""
    if connect and local:
        raise CliError("--connect and --local exclude each other")
    if tls is not None and not connect:
        raise CliError("--tls needs --connect: a local farm is this user's alone, without TLS")
    if participant is not None and tls is None:
        raise CliError("--as needs --tls: a participant is a secure farm's identity")
    return options.identity(tls, "analytic", participant)


def study_name(directory: Path, identity: "TlsIdentity | None") -> str:
    """A new study name for work on `directory`; on a secure farm its owner's, as the access
    policy requires (docs/security.md)."""
    from gainfarm.analytic.compose import new_study_name

    return new_study_name(directory, owner=identity.name if identity is not None else None)


@contextlib.contextmanager
def farm(connect: tuple[str, ...], workers: int | None) -> Iterator[list[str]]:
    """The endpoints to use: the given broker's, or else a local farm's (a local farm that
    cannot start is one line; what goes wrong later in the block is not relabelled)."""
    with own_farm(connect, workers) as (endpoints, _):
        yield endpoints


@contextlib.contextmanager
def own_farm(
    connect: tuple[str, ...], workers: int | None
) -> Iterator[tuple[list[str], frozenset[str] | None]]:
    """As `farm`, with the names of a local farm's workers (None with --connect): the only
    workers whose results a client of it takes (FarmClient's `own_workers`)."""
    if connect:
        yield list(connect), None
        return
    from gainfarm.analytic.evaluators.farm import FarmUnavailable
    from gainfarm.analytic.evaluators.local import LocalFarm

    with contextlib.ExitStack() as stack:
        try:
            local = stack.enter_context(LocalFarm(workers))
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
    from gainfarm.analytic.compose import CannotStart, claim

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


def farm_problem(connect: tuple[str, ...], error: Exception) -> str:
    """Why the farm cannot be had, in one line naming the option that chose it."""
    return f"{'--connect' if connect else 'local farm'}: {error}"


def followable(trajectories: Iterable["TrajectorySpec"], option: str = "--duration") -> None:
    """Refuse, in one line, a trajectory the iiwa cannot follow (out of reach, or too fast for
    its limits) before any job is sent: every episode of it would fail."""
    from gainfarm.analytic.compose import CannotStart, check_followable

    try:
        check_followable(trajectories)
    except CannotStart as error:
        raise CliError(f"{start_option(error.part, option)}: {error}") from None


def start_option(part: str, duration: str = "--duration") -> str:
    """The option that says the part of a run `tune.CannotStart` names."""
    return {"duration": duration, "placement": "--center/--size"}.get(part, f"--{part}")


def config_problem(error: "ValidationError") -> str:
    """A RunConfig's complaint in one line, naming the option when it is one field's."""
    from gainfarm.schemas.wire import describe

    text = describe(error)
    field, _, rest = text.partition(": ")
    if rest and field in ("algorithm", "objective_scaling", "pop", "seed", "keep"):
        return f"--{field.replace('_', '-')}: {rest}"
    return text.replace("generations and evaluations", "--generations and --evaluations")


def refuse_under_a_file(directory: Path, option: str) -> None:
    """Refuse, before anything runs, a directory to be made under a file: mkdir would say only
    "File exists" or "Not a directory", and after the work it was to hold."""
    if directory.exists():
        if not directory.is_dir():
            raise CliError(f"{option}: {str(directory)!r} is a file, not a directory")
        return
    ancestor = next((parent for parent in directory.parents if parent.exists()), None)
    if ancestor is not None and not ancestor.is_dir():
        raise CliError(f"{option}: cannot write {str(directory)!r}: {str(ancestor)!r} is a file")


def unwritable(error: OSError, then: str) -> CliError:
    """A file of a run that could not be written (disk full, read-only, no permission), in one
    line: the files are each whole or absent and the checkpoint is the last good one, so once
    the cause is gone the run goes on as `then` says."""
    where = f" {str(error.filename)!r}" if error.filename else ""
    return CliError(f"cannot write{where}: {error.strerror or error}; once it can, {then}")


def algorithm_names() -> tuple[str, ...]:
    """The optimisers a run may name: the built-in ones and the installed plug-ins' (their
    metadata read, none imported, so pymoo does not load to parse a command line)."""
    from gainfarm import plugins

    return plugins.names(plugins.ALGORITHMS)


def run_with_progress(
    go: Callable[["Watch", Callable[["CheckPlan"], None]], "TuningRun"],
    directory: Path,
    connect: tuple[str, ...],
) -> None:
    """Tune as `go` does (`tune`, or `tune_run` of an opened run), given what shows its progress
    (a live line, or a plain line a generation) and stops it at a Ctrl-C, and what says the
    held-out check as it starts; then say why it stopped, what replication found, which
    controller to use and how it did held out. `directory` is the run's."""
    from rich.console import Console

    from gainfarm import plugins
    from gainfarm.analytic.compose import TuningInterrupted
    from gainfarm.analytic.evaluators.farm import FarmUnavailable
    from gainfarm.analytic.tuning.check import advice_of, read_check
    from gainfarm.analytic.tuning.records import REPORT_MD
    from gainfarm.analytic.view.export import describe_pick, picks
    from gainfarm.analytic.view.progress import Display, RunDisplay
    from gainfarm.analytic.view.reports import stopped_text
    from gainfarm.cli import interrupts
    from gainfarm.schemas.limits import tally

    console = Console(stderr=True)

    @contextlib.contextmanager
    def watch(farm: "Evaluator") -> Iterator[Callable[["RunProgress"], None]]:
        with (
            Display(console, hushed=interrupts.INTERRUPTED.is_set) as display,
            RunDisplay(
                display, lambda: _workers(farm), lambda: getattr(farm, "waiting", None)
            ) as shown,
        ):

            def step(progress: "RunProgress") -> None:
                interrupts.check()  # between evaluations: a Ctrl-C Python held back
                shown.step(progress)

            yield step

    def checking(plan: "CheckPlan") -> None:
        # Seconds to minutes with no other line: say what runs. Through the live line's console,
        # which prints it above that line (a plain write would land on its end).
        # Loaded here, not before the run: run_report brings matplotlib (the run loads it while
        # its first results come in, compose._loading_figures).
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


def interrupted_text(run: "TuningRun", stage: str) -> str:
    """What a Ctrl-C leaves, in one line: the generations saved (a resume starts after them,
    which can be fewer than were shown: the records are written at most every RECORD_SECONDS),
    or, after the evolution, what is left to finish."""
    from gainfarm.analytic.compose import STAGES

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


def _workers(farm: "Evaluator") -> int | None:
    """How many workers the farm has now; None if the broker does not answer within 2 s."""
    from gainfarm.broker.status import query_status

    try:
        return query_status(farm.session, timeout=2.0).worker_count  # type: ignore[attr-defined]
    except Exception:  # no answer, a garbled one, or the session closed as the run ended
        return None
