"""`analytic validate` once it runs: what its function in analytic/commands/validate.py does."""

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.console import Console
from rich.table import Table

from gainfarm.analytic.calibration.gap import as_episode, gap, played_by, pooled, read_played
from gainfarm.analytic.calibration.logs import BadLog, Topics, read_log
from gainfarm.analytic.commands.shared import farm_problem
from gainfarm.analytic.commands.validate import REPORT
from gainfarm.analytic.commands.work.common import check_farm
from gainfarm.analytic.commands.work.tuning import claimed, farm, study_name
from gainfarm.analytic.evaluators.batch import run_batch
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.cli import values
from gainfarm.cli.app import CliError
from gainfarm.edges.files import write_atomically
from gainfarm.models import plant_preset, robot_of
from gainfarm.plugins import PluginError
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.wire import BadMessage

if TYPE_CHECKING:
    from gainfarm.analytic.calibration.gap import Played
    from gainfarm.analytic.calibration.logs import Topics
    from gainfarm.schemas.episode_log import EpisodeLog
    from gainfarm.schemas.robot import PlantSpec


def validate(
    twin: Path,
    logs: tuple[Path, ...],
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int | None,
    nominal: str,
    out: Path | None,
    played: tuple[Path, ...],
    joint_states: str,
    commands: str,
    motor_states: str,
    as_json: bool,
    robot: str | None,
) -> None:
    """`analytic validate` with its options as parsed (analytic/commands/validate.py)."""
    identity = check_farm(connect, local, tls, participant)
    twin_plant = values.plant_file(str(twin), option="TWIN").plant  # of a robot here, too
    arm = _arm(twin_plant, robot, twin)
    nominal_plant = _nominal(nominal, arm)
    topics = Topics(joint_states, commands, motor_states)
    try:
        candidates = [item for path in played for item in read_played(path)]
        logged = [_logged(path, topics, candidates, nominal_plant) for path in logs]
    except BadLog as error:
        raise CliError(str(error)) from None
    jobs = {}
    for index, log in enumerate(logged):
        for name, plant in (("twin", twin_plant), ("nominal", nominal_plant)):
            spec = log.metadata.spec
            jobs[f"e{index:02d}-{name}"] = EpisodeSpec(
                gains=spec.gains,
                trajectory=spec.trajectory,
                plant=plant,
                gravity_compensation=spec.gravity_compensation and plant.interface == "torque",
                objectives=spec.objectives,
            )
    out = out or Path("runs") / time.strftime("validate-%Y%m%d-%H%M%S")
    if (out / REPORT).exists():
        raise CliError(f"--out: {str(out)!r} already holds a validation; choose another")
    with claimed(out, "--out"), farm(connect, workers) as endpoints:
        try:
            client = FarmClient(endpoints, study_name(out, identity), out, identity=identity)
        except (ValueError, ConnectionError) as error:
            raise CliError(farm_problem(connect, error)) from None
        with client:
            try:
                results = {r.job_id: r for r in run_batch(client, jobs, out)}
            except BadMessage as error:
                raise CliError(str(error)) from None
    report = {"twin": str(twin), "nominal": nominal, "episodes": []}
    gaps: dict[str, list] = {"twin": [], "nominal": []}
    for index, (path, log) in enumerate(zip(logs, logged, strict=True)):
        entry = {"log": str(path)}
        logged_scores = score(log)
        for name in ("twin", "nominal"):
            result = results.get(f"e{index:02d}-{name}")
            if result is None or result.log is None or result.scores is None:
                reason = result.reason if result is not None else "no result"
                raise CliError(f"{str(path)!r}: its replay on the {name} failed: {reason}")
            one = gap(log, logged_scores, read_episode(result.log), result.scores)
            gaps[name].append(one)
            entry[name] = {
                "q_rms": one.q.tolist(),
                "torque_rms": one.torque.tolist(),
                "f_acc": one.f_acc,
                "f_t": one.f_t,
            }
        entry["logged"] = {"f_acc": logged_scores.f_acc, "f_t": logged_scores.f_t}
        report["episodes"].append(entry)
    summary = {}
    for name in ("twin", "nominal"):
        summary[name] = {
            "q_rms": pooled(gaps[name], "q").tolist(),
            "torque_rms": pooled(gaps[name], "torque").tolist(),
        }
    twin_q, nominal_q = (float(pooled(gaps[n], "q").mean()) for n in ("twin", "nominal"))
    summary["q_ratio"] = twin_q / nominal_q if nominal_q > 0 else float("nan")
    report["summary"] = summary
    write_atomically(out / REPORT, json.dumps(report, indent=1).encode())
    if as_json:
        click.echo(json.dumps(report))
        return
    _show(report, out, robot_of(arm).joint_names)


def _arm(twin_plant: "PlantSpec", robot: str | None, twin: Path) -> str:
    """The arm validated: the twin's, which --robot (if given) must be; one line if it is
    another, or not installed here."""
    arm = twin_plant.robot
    if robot is not None and robot != arm:
        raise CliError(f"--robot: TWIN {str(twin)!r} is a twin of {arm}, not of {robot}")
    try:
        robot_of(arm)
    except PluginError:
        raise CliError(
            f"TWIN: {str(twin)!r} is a twin of {arm!r}, an arm not installed here: give its "
            "description file, --robot FILE"
        ) from None
    return arm


def _nominal(nominal: str, arm: str) -> "PlantSpec":
    """--nominal as a plant of `arm`: a named plant its, a plant file one of it (else one line)."""
    if nominal in PLANTS:
        return plant_preset(nominal, arm)
    plant = values.model_spec(nominal, option="--nominal")
    if plant.robot != arm:
        raise CliError(
            f"--nominal: {nominal!r} is a plant of {plant.robot}, not of the twin's {arm}"
        )
    return plant


def _logged(
    path: Path, topics: "Topics", played: "list[Played]", nominal: "PlantSpec"
) -> "EpisodeLog":
    """LOG as an episode log: a gainfarm one as it is, a robot's bag as an episode of what it
    played; BadLog in one line."""
    log = read_log(path, topics)
    if not isinstance(log, EpisodeLog):  # a robot's bag
        return as_episode(log, played_by(log, played), nominal)
    if log.metadata.spec.plant.robot != nominal.robot:
        raise BadLog(
            f"{str(path)!r} is an episode of {log.metadata.spec.plant.robot}, not of the "
            f"twin's {nominal.robot}"
        )
    if log.metadata.spec.feedforward is not None:
        raise BadLog(
            f"{str(path)!r}: its controller adds a feed-forward model; validate replays PD "
            "controllers"
        )
    return log


def _show(report: dict, out: Path, joints: tuple[str, ...]) -> None:
    summary = report["summary"]
    table = Table(
        "joint",
        "q twin (mrad)",
        "q nominal (mrad)",
        "ratio",
        "τ twin (N·m)",
        "τ nominal (N·m)",
        title=f"simulation error of {len(report['episodes'])} logged episodes (RMS)",
    )
    for j, name in enumerate(joints):
        twin_q, nominal_q = summary["twin"]["q_rms"][j], summary["nominal"]["q_rms"][j]
        table.add_row(
            name,
            f"{twin_q * 1e3:.3g}",
            f"{nominal_q * 1e3:.3g}",
            f"{twin_q / nominal_q:.2f}" if nominal_q > 0 else "-",
            f"{summary['twin']['torque_rms'][j]:.3g}",
            f"{summary['nominal']['torque_rms'][j]:.3g}",
        )
    console = Console()
    console.print(table)
    episodes = Table(
        "log", "f_acc logged (mm)", "twin (mm)", "nominal (mm)", title="the objectives predicted"
    )
    for entry in report["episodes"]:
        episodes.add_row(
            Path(entry["log"]).name,
            f"{entry['logged']['f_acc'] * 1e3:.3g}",
            f"{entry['twin']['f_acc'] * 1e3:.3g}",
            f"{entry['nominal']['f_acc'] * 1e3:.3g}",
        )
    console.print(episodes)
    console.print(f"q error, twin against nominal: {summary['q_ratio']:.3g}x; {out / REPORT}")
