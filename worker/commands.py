"""What `worker`'s commands do once they run, one function each (the command line, worker/cli.py,
imports this module when a command runs: its imports here are the work's)."""

import contextlib
import hashlib
import importlib
import logging
import os
import re
import signal
import socket
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

import click
from click.core import ParameterSource
from pydantic import ValidationError

from gainfarm import plugins
from gainfarm.cli import values
from gainfarm.cli.app import CliError, setup_logging
from gainfarm.cli.gains import refuse_saturating, warn_far_outside_search
from gainfarm.cli.scores import show_scores
from gainfarm.cli.words import counted
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.controller import BadGains, read_controller, read_gains
from gainfarm.schemas.documents import BadDocument, read_bounded
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.mcap_episode import episode_bytes
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import PLANTS
from gainfarm.schemas.wire import NAME_PATTERN, NAME_RULE, describe
from gainfarm.worker.cli import gains as gains_option

if TYPE_CHECKING:
    from gainfarm.schemas.controller import Controller
    from gainfarm.schemas.gains import PDGains
    from gainfarm.schemas.robot import PlantSpec
    from gainfarm.schemas.trajectory import TrajectorySpec


def episode(
    out: Path,
    robot: str,
    trajectory: str,
    duration: float,
    kp: str | None,
    kd: str | None,
    gains_file: Path | None,
    joints: str,
    plant: str,
    payload: float | None,
    payload_com: tuple[float, ...] | None,
    trajectory_seed: int,
    center: str,
    size: float,
    gravity_compensation: bool,
    feedforward: Path | None,
    as_tuned: bool,
    as_json: bool,
) -> None:
    """`worker episode` with its options as parsed (worker/cli.py)."""
    # start-up: the robot's plug-in (its joints, centre and gains) loads MuJoCo; options a parse
    # refuses were refused before this (worker/cli.py)
    from gainfarm.models import robot_of

    model = values.model_spec(plant, joints) if plant not in PLANTS else None
    robot = _robot_of_plant(robot, model, plant)
    if as_tuned and gains_file is not None and not _given("robot"):
        robot = _tuned_robot(gains_file, robot)  # the controller's own arm, as the file says
    arm = robot_of(robot)
    gains, controller = (
        _file_gains(gains_file, arm.joint_names) if gains_file is not None else (None, None)
    )
    if not _given("center"):  # the robot's own workspace centre, exactly
        center = ",".join(repr(float(v)) for v in arm.workspace.center)
    (path,) = values.trajectories([trajectory], duration, trajectory_seed, center, size)
    model = _plant_of(plant, joints, robot, model)
    model = values.with_load(model, payload, payload_com, plant)
    if as_tuned:
        if payload is not None:
            raise CliError("--payload: --as-tuned runs the controller on its own plant")
        path, model = _as_tuned(controller, gains_file)
        arm = robot_of(model.robot)
    elif controller is not None:
        _warn_if_not_as_tuned(controller, gains_file, path, model)
    learned = values.feedforward_model(feedforward, robot)
    if learned is not None and gravity_compensation:
        raise CliError(
            "--feedforward and --gravity-compensation exclude each other: "
            "an inverse-dynamics model already holds the arm against gravity"
        )
    if gravity_compensation and model.interface == "fri":
        on = "the plant --as-tuned runs" if as_tuned else _plant_named(model)
        raise CliError(
            f"--gravity-compensation: {on} already adds the robot's own gravity compensation "
            f"({arm.torque_interface.name}); with --plant plain or --plant ideal the PD's torque "
            "is the whole motor torque, and this flag adds it"
        )
    joint_count = len(arm.joint_names)
    try:
        spec = EpisodeSpec(
            gains=gains or _option_gains(kp, kd, arm.default_gains, joint_count, arm.name),
            trajectory=path,
            plant=model,
            gravity_compensation=gravity_compensation,
            feedforward=hashlib.sha256(learned[0]).hexdigest() if learned else None,
        )
    except ValidationError as error:
        raise CliError(describe(error)) from None
    if len(spec.gains.kp) != joint_count:
        raise CliError(
            f"--gains: {str(gains_file)!r} holds {len(spec.gains.kp)} gains of each kind, for "
            f"{arm.name}'s {joint_count} joints"
        )
    _check_plant(spec.plant, plant)
    refuse_saturating([spec.gains], spec.plant, gains_file, arm)
    warn_far_outside_search("worker", [spec.gains], gains_file, arm)
    if not out.parent.is_dir():
        raise CliError(f"--out: directory {str(out.parent)!r} does not exist")
    # The simulation, its IK and references, the log's URDF (but --feedforward's and a plant
    # file's, which need MuJoCo, are checked by now):
    # start-up: MuJoCo loads once the options are checked
    from gainfarm.worker import ik, reference
    from gainfarm.worker.episode import run_episode
    from gainfarm.worker.job import drawing

    try:
        if not as_tuned and not _given("duration"):  # the robot's default for the kind
            trajectory = spec.trajectory
            chosen = reference.default_duration(trajectory, spec.plant.robot)
            spec = spec.model_copy(
                update={"trajectory": trajectory.model_copy(update={"duration": chosen})}
            )
        log = run_episode(spec, learned[1] if learned is not None else None)
    except ik.UnreachablePath as error:
        raise CliError(f"{'--as-tuned' if as_tuned else '--center/--size'}: {error}") from None
    except reference.InfeasibleReference as error:
        raise CliError(f"{'--as-tuned' if as_tuned else '--duration'}: {error}") from None
    try:
        write_atomically(out, episode_bytes(log, drawing(spec.plant.robot)))
    except OSError as error:
        raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror}") from None
    show_scores(score(log), out, as_json)


def _given(name: str) -> bool:
    """Whether the option of parameter `name` was given on the command line."""
    source = click.get_current_context().get_parameter_source(name)
    return source is ParameterSource.COMMANDLINE


def _robot_of_plant(robot: str, model: "PlantSpec | None", plant: str) -> str:
    """The episode's robot: --robot's, or a plant file's own arm (a twin is of one arm); both
    given and different: one line naming them."""
    if model is None or model.robot == robot:
        return robot
    if _given("robot"):
        raise CliError(
            f"--robot: {robot!r}, but the plant file {plant!r} is a plant of {model.robot!r}"
        )
    return model.robot


def _plant_of(plant: str, joints: str | None, robot: str, model: "PlantSpec | None") -> "PlantSpec":
    """--plant's PlantSpec on the robot: a named plant is that preset of the robot's
    (models.plant_preset), a plant file its own (already read: `model`)."""
    if model is not None:
        return model
    # start-up: MuJoCo, as the robot's (loaded by now)
    from gainfarm.models import plant_preset

    preset = plant_preset(plant, robot)
    return preset if joints is None else preset.model_copy(update={"joints": joints})


def _check_plant(spec: "PlantSpec", plant: str) -> None:
    """One line naming --plant (or --payload) if the robot cannot be this plant: a per-joint
    number of another count, an inertial set it lacks, a payload past its rating, springs its
    physics step cannot hold."""
    # start-up: MuJoCo, as the robot's (loaded by now)
    from gainfarm.models import PlantError, resolve, robot_of

    try:
        resolved = resolve(spec)
    except PlantError as error:
        field, said = str(error).split(": ", 1)
        if field == "payload":  # the told load's, or a plant file's untold payload
            raise CliError(f"--payload: {said}") from None
        raise CliError(f"--plant: {error}") from None
    try:
        robot_of(spec).build(resolved)
    except ValueError as error:
        raise CliError(f"--plant: {plant!r}: {error}") from None


def _tuned_robot(path: Path, robot: str) -> str:
    """The arm an exported controller was tuned on (its source plant's robot), or `robot` if
    the file is not one (its reading, later, says what is wrong)."""
    try:
        controller = read_controller(read_bounded(path))
    except (OSError, BadDocument):
        return robot
    return robot if controller is None else controller.source.model.robot


def _option_gains(
    kp: str | None, kd: str | None, defaults: "PDGains", joints: int, robot: str
) -> "PDGains":
    """--kp and --kd, each the robot's default gains if not given, one per joint of it."""
    chosen = []
    for option, text, default in (("--kp", kp, defaults.kp), ("--kd", kd, defaults.kd)):
        if text is None:
            chosen.append(tuple(default))
            continue
        given = gains_option(option, text)
        if len(given) != joints:
            raise CliError(f"{option}: {len(given)} gains for {robot}'s {joints} joints")
        chosen.append(given)
    return PDGains(kp=chosen[0], kd=chosen[1])


def start(
    connect: tuple[str, ...],
    name: str | None,
    tls: Path | None,
    model_cache: Path | None,
    log_memory: int,
    threads: int | None,
    robot: str,
    log_level: str,
) -> None:
    """`worker start` with its options as parsed (worker/cli.py). `robot` is registered in this
    process already, if it came from a description file (gainfarm.cli.options.robot): the
    worker serves it beside every installed arm."""
    setup_logging("worker", log_level)
    # On a secure farm the router lets a worker lease only under its certificate's name.
    identity = values.identity(tls, "worker", name, name_option="--name")
    if identity is not None:
        name = identity.name
    name = name or re.sub(r"[^A-Za-z0-9_.\-]", "-", f"{socket.gethostname()}-{os.getpid()}")
    if not re.fullmatch(NAME_PATTERN, name):
        raise CliError(f"--name: {name!r} is not {NAME_RULE}")
    # start-up: Zenoh and MuJoCo load once the options are checked
    from gainfarm.worker.service import CobotWorker, ModelCache, NameTaken

    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    log = logging.getLogger("gainfarm.worker")
    models = ModelCache(model_cache)  # one for the process: a reconnect keeps what it fetched
    tries = 0
    while not stop.is_set():
        try:
            cobot = CobotWorker(
                connect,
                name,
                identity,
                models,
                log_memory * 2**20,
                threads=threads or cores(),
                on_idle=warm_up,
            )
        except NameTaken as error:
            raise CliError(str(error)) from None
        except ValueError as error:  # the name is checked above: what is left is an endpoint
            raise CliError(f"--connect: {error}") from None
        except ConnectionError as error:
            cobot = None
            why = str(error)
        if cobot is not None and not cobot.broker_serves():
            # Its router listens a moment before the broker serves on it: a request for work
            # then would go unanswered, and be asked again only a second later.
            cobot.close()
            cobot, why = None, f"no broker serves on {', '.join(connect)} yet"
        if cobot is None:
            # A farm's workers often start before its broker (a local farm starts them all at
            # once): tried again at once and said only if it lasts.
            pause = retry_pause(tries)
            tries += 1
            if tries == QUIET_TRIES:
                log.warning("%s; retrying every second", why)
            stop.wait(pause)
            continue
        tries = 0
        with cobot:
            log.info(
                "worker %s serving %s on %s, arms %s",
                name,
                ", ".join(connect),
                counted(cobot.threads, "thread"),
                ", ".join(plugins.names(plugins.ROBOTS)),
            )
            done = cobot.serve_until(stop)
        log.info("worker %s stopped after %d jobs", name, done)


# Connecting again: at first every RETRY_FIRST s, doubling up to RETRY_SECONDS; the first
# QUIET_TRIES failures (about a second) are not said: a broker started beside the worker listens
# within that.
RETRY_FIRST = 0.05


RETRY_SECONDS = 1.0


QUIET_TRIES = 5


def retry_pause(tries: int) -> float:
    """How long to wait before connecting again, after `tries` failures in a row."""
    return min(RETRY_SECONDS, RETRY_FIRST * 2**tries)


def warm_up() -> None:
    """Load, on a thread of its own while the worker waits for work, what scoring a job loads
    on first use: scipy.signal (schemas.objectives.chatter), about a second of the first job's
    time otherwise. Only once idle: while a local farm starts, the analytic process's own start
    needs the cores. A job that needs it before it is loaded waits for this import (Python's
    import lock) rather than doing it twice; if it fails here, the job's says why."""
    if "scipy.signal" not in sys.modules:
        threading.Thread(target=_load_scoring, name="warm-up", daemon=True).start()


def _load_scoring() -> None:
    with contextlib.suppress(Exception):
        importlib.import_module("scipy.signal")


def cores() -> int:
    """The cores this process may run on (its CPU affinity, as a container's --cpuset sets)."""
    return len(os.sched_getaffinity(0))


def _file_gains(path: Path, joints: tuple[str, ...]) -> "tuple[PDGains, Controller | None]":
    """--gains: the one controller in the file, a gain per one of `joints` (the robot's), and
    the file as a Controller, if it is an exported one; --kp and --kd may not be given beside
    it."""
    context = click.get_current_context()
    given = [
        f"--{name}"
        for name in ("kp", "kd")
        if context.get_parameter_source(name) is ParameterSource.COMMANDLINE
    ]
    if given:
        raise CliError(f"--gains and {' and '.join(given)} exclude each other: give one of them")
    try:
        raw = read_bounded(path)
    except OSError as error:
        raise CliError(f"--gains: cannot read {str(path)!r}: {error.strerror}") from None
    except BadDocument as error:
        raise CliError(f"--gains: {str(path)!r}: {error}") from None
    try:
        candidates = read_gains(raw, joints)
    except BadGains as error:
        raise CliError(f"--gains: {str(path)!r}: {error}") from None
    if len(candidates) != 1:
        raise CliError(
            f"--gains: {str(path)!r} holds {len(candidates)} candidates and an episode runs one; "
            "`analytic export RUN --member ...` writes one (`analytic batch --gains` runs many)"
        )
    return candidates[0], read_controller(raw)


# The options that choose the episode's trajectory and plant: what --as-tuned takes from the file.
_CHOSEN = ("trajectory", "duration", "trajectory_seed", "center", "size", "plant", "joints")


def _as_tuned(
    controller: "Controller | None", path: Path | None
) -> "tuple[TrajectorySpec, PlantSpec]":
    """--as-tuned: the trajectory and plant the controller file says it was tuned on."""
    if controller is None:
        raise CliError(
            "--as-tuned needs --gains with a controller from `analytic export` (it says what the "
            "gains were tuned on)"
        )
    context = click.get_current_context()
    for name in _CHOSEN:
        if context.get_parameter_source(name) is ParameterSource.COMMANDLINE:
            flag = "--" + name.replace("_", "-")
            raise CliError(f"--as-tuned and {flag} exclude each other: the file says which")
    return controller.source.trajectories[0], controller.source.model


def _warn_if_not_as_tuned(
    controller: "Controller", path: Path | None, trajectory: "TrajectorySpec", plant: "PlantSpec"
) -> None:
    """One line on stderr if the episode is not what the controller was tuned on, naming both
    sides (the trajectories by what tells them apart, the plants by name and joints): its scores
    then say how it carries over, not what its run found."""
    source = controller.source
    differs = []
    if trajectory not in source.trajectories:
        # What tells them apart: the fields in which the run's trajectory differs from the
        # nearest one tuned on, said of every trajectory.
        fields = min(
            (_differing(trajectory, tuned) for tuned in source.trajectories),
            key=len,
            default=[],
        )
        tuned = " and ".join(_described(t, fields) for t in source.trajectories)
        differs.append(f"tuned on {tuned}, run on {_described(trajectory, fields)}")
    if plant != source.model:
        joints = plant.joints != source.model.joints
        was, now = _plant_named(source.model, joints), _plant_named(plant, joints)
        if was == now:  # two custom plants, with the same joints
            now = "another custom plant"
        differs.append(f"tuned on {was}, run on {now}")
    if differs:
        click.echo(
            f"worker: warning: --gains {str(path)!r}: {'; '.join(differs)} (--as-tuned runs "
            "it as tuned)",
            err=True,
        )


# A trajectory's fields, as _described says them, in that order (kind and duration always).
_SAID = ("seed", "center", "size", "turns", "waypoints", "twist", "harmonics")


def _differing(trajectory: "TrajectorySpec", other: "TrajectorySpec") -> list[str]:
    return [
        name
        for name in ("kind", "duration", *_SAID)
        if getattr(trajectory, name) != getattr(other, name)
    ]


def _described(trajectory: "TrajectorySpec", fields: "list[str] | None" = None) -> str:
    """'the 3 s spiral', with the `fields` that tell it from another ('the 3 s spiral (size
    0.1 m, centre 0.5,0,0.4 m)'); a seed other than 0 is always said."""
    fields = fields or []
    said = []
    for name in _SAID:
        value = getattr(trajectory, name)
        if name not in fields and not (name == "seed" and value):
            continue
        if name == "center":
            said.append(f"centre {','.join(f'{v:g}' for v in value)} m")
        elif name in ("size", "twist"):
            said.append(f"{name} {value:g} {'m' if name == 'size' else 'rad'}")
        else:
            said.append(f"{name} {value:g}")
    detail = f" ({', '.join(said)})" if said else ""
    return f"the {trajectory.duration:g} s {trajectory.kind}{detail}"


def _plant_named(plant: "PlantSpec", joints: bool = False) -> str:
    """'the realistic plant' (a named plant of its robot, with any joints), or 'a custom plant';
    with `joints`, which joints it has: 'the realistic plant with rigid joints'."""
    # start-up: MuJoCo, as the robot's (loaded by now)
    from gainfarm.models import plant_preset

    name = next(
        (
            f"the {name} plant"
            for name in PLANTS
            if plant_preset(name, plant.robot).model_copy(update={"joints": plant.joints}) == plant
        ),
        "a custom plant",
    )
    return f"{name} with {plant.joints} joints" if joints else name
