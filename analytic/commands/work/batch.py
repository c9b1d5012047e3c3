"""`analytic batch` once it runs: what its function in analytic/commands/batch.py does."""

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.console import Console
from rich.table import Table

from gainfarm.analytic.commands.shared import farm_problem
from gainfarm.analytic.commands.work.common import (
    centre,
    check_farm,
    on_the_robot,
    robot_plant,
)
from gainfarm.analytic.commands.work.start import STANDARD
from gainfarm.analytic.commands.work.tuning import claimed, farm, followable, study_name
from gainfarm.analytic.evaluators.batch import EVALUATIONS, batch_jobs, run_batch
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.tuning.records import front_joints, read_front
from gainfarm.analytic.view.progress import Display
from gainfarm.cli import interrupts, values
from gainfarm.cli.app import CliError
from gainfarm.cli.gains import refuse_saturating, warn_far_outside_search
from gainfarm.cli.scores import DIVERGED_TEXT, print_title
from gainfarm.models.dynamics import digest
from gainfarm.schemas.controller import BadGains, read_gains
from gainfarm.schemas.documents import BadDocument, read_bounded
from gainfarm.schemas.wire import BadMessage

if TYPE_CHECKING:
    from gainfarm.analytic.evaluators.evaluator import EpisodeResult
    from gainfarm.schemas.gains import PDGains


def batch(
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int | None,
    gains_file: Path | None,
    kinds: tuple[str, ...],
    duration: float | None,
    trajectory_seed: int,
    center: str | None,
    size: float,
    robot: str,
    joints: str,
    plant: str,
    payload: float | None,
    payload_com: tuple[float, ...] | None,
    feedforward: Path | None,
    run_dir: Path | None,
    deadline: float,
    as_json: bool,
) -> None:
    """`analytic batch` with its options as parsed (analytic/commands/batch.py); `center` and
    `duration` None: the robot's workspace centre and each kind's default duration on it."""
    if not connect and not local:  # batch has no default farm
        raise CliError("say where the farm is: --connect ENDPOINT or --local")
    identity = check_farm(connect, local, tls, participant)
    model = values.with_load(robot_plant(plant, joints, robot), payload, payload_com, plant)
    # start-up: the robot's module (MuJoCo) is loaded by now, for the plant
    from gainfarm.models import robot_of

    arm = robot_of(model)
    candidates = _candidates(gains_file, arm.default_gains, arm.joint_names)
    # Episodes that saturate every tick are refused, as `worker episode` refuses them.
    refuse_saturating(candidates, model, gains_file, arm)
    if gains_file is not None:
        warn_far_outside_search("analytic", candidates, gains_file, arm)
    where = centre(center, model.robot)
    given = values.trajectories(
        kinds, STANDARD if duration is None else duration, trajectory_seed, where, size
    )
    trajectories = on_the_robot(given, duration, model.robot)
    followable(trajectories, robot=model.robot)
    learned = values.feedforward_model(feedforward, model.robot)
    models = {digest(learned[0]): learned[0]} if learned is not None else {}
    jobs = batch_jobs(candidates, trajectories, model, *models)
    run_dir = run_dir or Path("runs") / time.strftime("batch-%Y%m%d-%H%M%S")
    if (run_dir / EVALUATIONS).exists():
        raise CliError(f"--run-dir: {str(run_dir)!r} already holds a batch; choose another")
    with claimed(run_dir, "--run-dir") as keep, farm(connect, workers, model.robot) as endpoints:
        try:
            client = FarmClient(
                endpoints,
                study_name(run_dir, identity),
                run_dir,
                deadline=deadline,
                identity=identity,
                models=models,
            )
        except (ValueError, ConnectionError) as error:
            raise CliError(farm_problem(connect, error)) from None
        keep()  # once the farm answers, the episodes are the batch's: kept, even if stopped
        with client, Display(enabled=not as_json) as display:
            done = 0

            def report(result: "EpisodeResult") -> None:
                nonlocal done
                interrupts.check()
                done += 1
                display.show(f"{done} of {len(jobs)} evaluated")
                if done * 10 // len(jobs) != (done - 1) * 10 // len(jobs):  # every tenth
                    display.log(f"{done} of {len(jobs)} evaluated")
                if as_json:
                    click.echo(json.dumps(_summary(result)))

            try:
                evaluations = run_batch(client, jobs, run_dir, report)
            except BadMessage as error:
                raise CliError(str(error)) from None
    if not as_json:
        _print_evaluations(evaluations, run_dir, EVALUATIONS)


def _candidates(path: Path | None, defaults: "PDGains", joints: tuple[str, ...]) -> list["PDGains"]:
    """--gains' candidates for an arm of `joints` (its `defaults` if none): an exported
    controller or a list of gains, JSON or YAML (schemas.controller.read_gains), or every member
    of a run's front.csv; one line if they are not one pair per joint."""
    if path is None:
        return [defaults]
    try:
        raw = read_bounded(path)
    except OSError as error:
        raise CliError(f"--gains: cannot read {str(path)!r}: {error.strerror}") from None
    except BadDocument as error:
        raise CliError(f"--gains: {str(path)!r}: {error}") from None
    if raw.startswith(b"kp1,"):  # a CSV whose header is front.csv's
        if front_joints(path) != len(joints):
            raise CliError(
                f"--gains: {str(path)!r} is a front of a {front_joints(path)}-joint arm, not of "
                f"the {len(joints)} joints of --robot's ({', '.join(joints)})"
            )
        try:
            front = read_front(path)
        except ValueError as error:
            # The reader's message starts with the path: named once, quoted as ours are.
            reason = str(error).removeprefix(f"{path}: ")
            raise CliError(f"--gains: {str(path)!r}: {reason}") from None
        if not front:
            raise CliError(f"--gains: {str(path)!r} is a front.csv with no members")
        return [member.gains for member in front]
    try:
        return read_gains(raw, joints)
    except BadGains as error:
        raise CliError(f"--gains: {str(path)!r}: {error}") from None


def _summary(result: "EpisodeResult") -> dict[str, object]:
    scores = result.scores.model_dump() if result.scores else {}
    episode = str(result.log) if result.log else None
    return {
        "job_id": result.job_id,
        "status": result.status.value,
        **scores,
        "reason": result.reason,
        "episode": episode,
    }


def _print_evaluations(evaluations: list["EpisodeResult"], run_dir: Path, name: str) -> None:
    table = Table(
        "job",
        "status",
        "f_acc (mm)",
        "f_t ((N·m)²)",
        "worker",
    )
    for result in evaluations:
        scores = result.scores
        table.add_row(
            result.job_id,
            result.status if not result.reason else f"{result.status}: {result.reason}",
            f"{scores.f_acc * 1000:.3f}" if scores else "",
            f"{scores.f_t:.4g}" if scores else "",
            result.worker,
        )
    print_title(Console(), f"{run_dir}/{name}")
    Console().print(table)
    if any(result.scores and result.scores.diverged for result in evaluations):
        Console().print(DIVERGED_TEXT, highlight=False)
