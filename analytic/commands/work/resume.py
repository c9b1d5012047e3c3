"""`analytic resume` once it runs (analytic/commands/resume.py declares it): its options checked,
then the run opened and run on with its progress shown (work/tuning.py)."""

from pathlib import Path

from gainfarm.analytic.commands.work.common import check_farm
from gainfarm.analytic.tuning.records import CONFIG_JSON
from gainfarm.cli.app import CliError


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
    # start-up: MuJoCo, Zenoh, pymoo and rich load once the options are checked
    from gainfarm.analytic.commands.work import tuning

    tuning.resume_run(run_dir, tuning.FarmOptions(connect, workers, identity))
