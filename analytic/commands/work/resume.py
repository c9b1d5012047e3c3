"""`analytic resume` once it runs (analytic/commands/resume.py declares it): its options checked,
then the run opened and run on with its progress shown (work/tuning.py)."""

from pathlib import Path

from gainfarm import plugins
from gainfarm.analytic.commands.work.common import check_farm
from gainfarm.analytic.tuning.records import CONFIG_JSON
from gainfarm.cli.app import CliError
from gainfarm.schemas.documents import BadDocument, load_json, read_bounded
from gainfarm.schemas.robot import DEFAULT_ROBOT


def resume(
    run_dir: Path,
    robot: str | None,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int | None,
) -> None:
    """`analytic resume` with its options as parsed (analytic/commands/resume.py); `robot`
    None: not given."""
    identity = check_farm(connect, local, tls, participant)
    if not (run_dir / CONFIG_JSON).is_file():
        raise CliError(f"{str(run_dir)!r} holds no run (no {CONFIG_JSON})")
    _same_robot(run_dir, robot)
    # start-up: MuJoCo, Zenoh, pymoo and rich load once the options are checked
    from gainfarm.analytic.commands.work import tuning

    tuning.resume_run(run_dir, tuning.FarmOptions(connect, workers, identity))


def _same_robot(run_dir: Path, robot: str | None) -> None:
    """One line naming --robot if the run is of another arm than --robot's, or of one that is
    not here (a described arm's run needs its description file again)."""
    try:
        config = load_json(read_bounded(run_dir / CONFIG_JSON))
        plant = config.get("plant", config.get("model")) or {}
        named = plant.get("robot", DEFAULT_ROBOT) if isinstance(plant, dict) else DEFAULT_ROBOT
    except (OSError, BadDocument, AttributeError, ValueError):
        return  # an unreadable config.json is the opening's to say
    if robot is not None and named != robot:
        raise CliError(f"--robot: {robot}, but the run in {str(run_dir)!r} is of {named}")
    if named not in plugins.names(plugins.ROBOTS):
        raise CliError(
            f"--robot: the run in {str(run_dir)!r} is of {named!r}, which is no robot here: "
            "give its description file (--robot FILE)"
        )
