"""`analytic resume` once it runs: what its function in analytic/commands/resume.py does."""

from collections.abc import Callable
from pathlib import Path

from gainfarm.analytic.commands.work.common import check_farm
from gainfarm.analytic.commands.work.tuning import run_with_progress
from gainfarm.analytic.compose import CannotStart, Farm, Watch, complete, tune_run
from gainfarm.analytic.tuning.check import CheckPlan
from gainfarm.analytic.tuning.checkpoint import CheckpointRefused
from gainfarm.analytic.tuning.records import CONFIG_JSON
from gainfarm.analytic.tuning.run import RunBusy, TuningRun
from gainfarm.cli.app import CliError
from gainfarm.schemas.wire import one_line


def resume(
    run_dir: Path,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int | None,
) -> None:
    """`analytic resume` with its options as parsed (analytic/commands/resume.py)."""
    identity = check_farm(connect, local, tls, participant)
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
        raise CliError(f"{str(run_dir)!r}: unreadable run ({one_line(error)})") from None
    if complete(run):  # else what a Ctrl-C after the evolution left is done now
        run.close()
        raise CliError(f"{str(run_dir)!r} has finished: {run.state.stopped}")

    def go(watch: Watch, on_check: Callable[[CheckPlan], None]) -> TuningRun:
        tune_run(run, Farm(connect, workers, identity), watch=watch, on_check=on_check)
        return run

    try:
        run_with_progress(go, run_dir, connect)
    except CannotStart as error:  # its feed-forward model file is missing, or another
        raise CliError(str(error)) from None
