"""An arm's recorded episodes, as calibration reads them: what a robot-side log holds.

A real arm reports its joint angles, velocities and torque sensors (`sensor_msgs/JointState` on
/joint_states), the torques its controller commanded (/joint_commands) and, if it can, its motor
angles (/motor_states). gainfarm's own episode logs hold the same channels, and their metadata
names the controller that ran (its gains, its reference, the side it fed back, the interface):
what a user of a real arm knows too. The plant's numbers in that metadata are never read: a
hidden arm's log must not tell calibration the answer.

A recording is of one arm (`robot`, the iiwa 14 by default): a bag's joints are read in that
arm's order, and an episode log of another arm is refused.

One thing differs: gainfarm logs the command as the motors applied it (after the delay), a real
arm's client logs what it sent. The PD law and the logged measurements give back what was sent.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from rosbags.highlevel import AnyReader

from gainfarm.models import robot_of
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, check_chunks, read_episode
from gainfarm.schemas.robot import DEFAULT_ROBOT
from gainfarm.schemas.trajectory import CONTROL_PERIOD, CONTROL_PERIOD_NS, TrajectorySpec

if TYPE_CHECKING:
    from rosbags.interfaces import Connection


class BadLog(ValueError):
    """A log calibration cannot use: the message names the file and why, in one line."""


class UnreadableBag(BadLog):
    """A file or directory rosbags cannot read as a bag at all (not one whose topics are wrong):
    `reason` is rosbags' own word on it."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Recording:
    """One episode of an arm, every array (n, N) at the 500 Hz control rate, SI units (N the
    arm's joints)."""

    name: str
    q: np.ndarray  # measured link-side angles
    qd: np.ndarray  # measured link-side velocities
    tau: np.ndarray  # measured joint torques (the torque sensors)
    command: np.ndarray  # the torque the controller sent (on top of the robot's gravity model)
    theta: np.ndarray | None  # measured motor-side angles, if the arm reports them
    theta_d: np.ndarray | None  # measured motor-side velocities
    fed_back: Literal["motor", "link"]  # the side whose angles the controller (and FRI) read
    # What ran, if known: replaying the episode through a plant needs both.
    gains: PDGains | None = None
    trajectory: TrajectorySpec | None = None
    robot: str = DEFAULT_ROBOT  # the arm it is of

    @property
    def ticks(self) -> int:
        return len(self.q)

    @property
    def feedback(self) -> tuple[np.ndarray, np.ndarray]:
        """The angles and velocities the robot's controller read."""
        if self.fed_back == "motor" and self.theta is not None and self.theta_d is not None:
            return self.theta, self.theta_d
        return self.q, self.qd


@dataclass(frozen=True)
class Topics:
    """Where a robot's bag keeps what calibration reads: `sensor_msgs/JointState` topics."""

    joint_states: str = "/joint_states"  # position, velocity, effort (the torque sensors)
    commands: str = "/joint_commands"  # effort: the torque the controller sent
    motor_states: str = "/motor_states"  # position, velocity of the motors; optional


def read_recording(path: Path, topics: Topics = Topics(), robot: str = DEFAULT_ROBOT) -> Recording:
    """One episode of `robot`: a gainfarm episode log, or else a ROS 2 bag (a directory, or an
    MCAP or SQLite file) a robot recorded; BadLog in one line naming the file."""
    log = read_log(path, topics, robot)
    return _from_episode(Path(path), log, robot) if isinstance(log, EpisodeLog) else log


def read_log(
    path: Path, topics: Topics = Topics(), robot: str = DEFAULT_ROBOT
) -> "EpisodeLog | Recording":
    """The file as it is: a gainfarm episode log, or else a robot's ROS 2 bag's recording (of
    `robot`'s joints), each read once; BadLog in one line naming the file."""
    path = Path(path)
    name = str(path)
    if not path.exists():
        raise BadLog(f"{name!r}: no such file")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        # Checked here: rosbags would say that its metadata file "'DIR' does not exist".
        raise BadLog(f"{name!r} is a directory but no ROS 2 bag (no metadata.yaml in it)")
    if path.is_file():
        try:
            return read_episode(path)
        except OSError as error:
            raise BadLog(f"{name!r}: cannot read: {error.strerror}") from None
        except NotAnEpisodeLog as error:
            # The reader's message starts with the path: named once, quoted as ours are.
            reason = str(error).removeprefix(f"{path}: ")
            if not _rosbag(path):
                raise BadLog(f"{name!r}: {reason}") from None
        try:
            return read_bag(path, topics, robot)
        except UnreadableBag as error:
            # An MCAP file that is neither: a truncated episode log as likely as a broken bag,
            # so both readers' reasons.
            raise BadLog(
                f"{name!r}: neither an episode log ({reason}) nor a ROS 2 bag rosbags can read "
                f"({error.reason})"
            ) from None
    return read_bag(path, topics, robot)


def _check_bounds(path: Path) -> None:
    """Refuse, before rosbags reads it, a bag whose MCAP files would decompress past
    MAX_EPISODE_BYTES: rosbags inflates each chunk to whatever its data says (a 200 kB file to
    gigabytes). A bag's SQLite files hold their messages as they are, bounded by their size."""
    files = [path] if path.is_file() else sorted(path.glob("*.mcap"))
    for file in files:
        if not _mcap(file):
            continue
        try:
            check_chunks(file)
        except NotAnEpisodeLog as error:
            raise BadLog(f"{str(path)!r}: {str(error).removeprefix(f'{file}: ')}") from None


def _mcap(path: Path) -> bool:
    try:
        with path.open("rb") as file:
            return file.read(5) == b"\x89MCAP"
    except OSError:  # rosbags says why, as for any file it cannot read
        return False


def _rosbag(path: Path) -> bool:
    """Whether `path` could be a ROS 2 bag's file that is not a gainfarm episode log."""
    with path.open("rb") as file:
        head = file.read(16)
    return head.startswith(b"\x89MCAP") or head.startswith(b"SQLite format 3")


def _from_episode(path: Path, log: EpisodeLog, robot: str = DEFAULT_ROBOT) -> Recording:
    spec = log.metadata.spec
    if spec.plant.robot != robot:  # the arm's name is the user's to know, not the plant's numbers
        raise BadLog(
            f"{str(path)!r}: an episode of {spec.plant.robot}, not of {robot} (--robot names "
            "the arm the logs are of)"
        )
    if log.metadata.diverged:
        raise BadLog(f"{str(path)!r}: the episode diverged ({log.metadata.divergence})")
    if log.metadata.control_period != CONTROL_PERIOD:
        raise BadLog(
            f"{str(path)!r}: logged every {log.metadata.control_period * 1e3:g} ms, the plant's "
            f"rate is {CONTROL_PERIOD * 1e3:g} ms"
        )
    if spec.feedforward is not None or spec.gravity_compensation:
        raise BadLog(
            f"{str(path)!r}: its commands are more than a PD's (a feed-forward): calibration "
            "replays plain PD episodes, such as `analytic excite`'s"
        )
    if log.ticks < MIN_TICKS:
        raise BadLog(f"{str(path)!r}: {log.ticks} ticks, fewer than the {MIN_TICKS} a fit needs")
    # The controller's side and interface are its settings, known to the user: not the plant's.
    side = spec.plant.feedback
    angle, rate = (log.theta, log.theta_d) if side == "motor" else (log.q, log.qd)
    kp, kd = np.asarray(spec.gains.kp), np.asarray(spec.gains.kd)
    sent = kp * (log.q_des - angle) + kd * (log.qd_des - rate)
    elastic = not np.array_equal(log.theta, log.q)
    return Recording(
        name=Path(path).name,
        q=log.q,
        qd=log.qd,
        tau=log.tau,
        command=sent,
        theta=log.theta if elastic else None,
        theta_d=log.theta_d if elastic else None,
        fed_back=side,
        gains=spec.gains,
        trajectory=spec.trajectory,
        robot=robot,
    )


MIN_TICKS = 500  # 1 s: shorter says little beyond its start
# A tick's stamp may be late by this share of a period (a real-time loop's jitter); a stamp
# later than that is a gap, ticks the robot did not log.
JITTER = 0.25
# A joint's measured angle may not move more than this many times its speed limit allows in a
# tick: more is a jump (an encoder glitch, a restart), not motion.
JUMP = 3.0
JOINT_STATE = "sensor_msgs/msg/JointState"


def read_bag(path: Path, topics: Topics = Topics(), robot: str = DEFAULT_ROBOT) -> Recording:
    """One episode a robot recorded as a ROS 2 bag: its joint states, commanded torques and, if
    logged, motor states, each `sensor_msgs/JointState` at the plant's 500 Hz (a bag at an
    integer multiple of it, 1 kHz say, is taken every k-th message); BadLog in one line naming
    the file and what is missing or wrong. Its joints are `robot`'s, named so or in its order."""
    name = str(path)
    joints = robot_of(robot).joint_names
    _check_bounds(Path(path))
    try:
        with AnyReader([Path(path)]) as reader:
            found = {c.topic: c for c in reader.connections}
            wanted = {"joint_states": topics.joint_states, "commands": topics.commands}
            if topics.motor_states in found:
                wanted["motor_states"] = topics.motor_states
            for role, topic in wanted.items():
                option = "--" + role.replace("_", "-")
                if topic not in found:
                    raise BadLog(
                        f"{name!r}: no {topic} topic ({_ROLES[role]}; {option} names another)"
                    )
                if found[topic].msgtype != JOINT_STATE:
                    raise BadLog(
                        f"{name!r}: {topic} holds {found[topic].msgtype}, not {JOINT_STATE}"
                    )
            columns = {
                role: _joint_states(reader, found[topic], joints) for role, topic in wanted.items()
            }
    except BadLog:
        raise
    except Exception as error:  # rosbags' errors have no common base: any is the file's fault
        raise UnreadableBag(
            f"{name!r}: not a ROS 2 bag rosbags can read ({error})", str(error)
        ) from None
    states = columns["joint_states"]
    if states.effort is None:
        raise BadLog(
            f"{name!r}: {topics.joint_states} has no effort (the measured joint torques): "
            "calibration needs the torque sensors"
        )
    commands = columns["commands"]
    if commands.effort is None:
        raise BadLog(f"{name!r}: {topics.commands} has no effort (the commanded torques)")
    step = _step(name, topics.joint_states, states.stamps)
    ticks = _ticks(name, topics.joint_states, states.stamps, step)
    q = states.position[ticks]
    _no_jumps(name, topics.joint_states, q, states.stamps[ticks], robot)
    command = _aligned(name, topics.commands, commands, states.stamps[ticks]).effort
    motor = columns.get("motor_states")
    theta = theta_d = None
    if motor is not None:
        motor = _aligned(name, topics.motor_states, motor, states.stamps[ticks])
        theta, theta_d = motor.position, motor.velocity
    velocity = states.velocity[ticks] if states.velocity is not None else None
    if velocity is None:
        raise BadLog(f"{name!r}: {topics.joint_states} has no velocity")
    if len(q) < MIN_TICKS:
        raise BadLog(f"{name!r}: {len(q)} ticks, fewer than the {MIN_TICKS} a fit needs")
    for what, values in (
        ("torques", states.effort[ticks]),
        ("commands", command),
        ("velocities", velocity),
    ):
        if not np.isfinite(values).all():
            raise BadLog(f"{name!r}: its {what} hold values that are not numbers")
    return Recording(
        name=Path(path).name,
        q=q,
        qd=velocity,
        tau=states.effort[ticks],
        command=command,
        theta=theta,
        theta_d=theta_d,
        fed_back="motor" if theta is not None else "link",
        robot=robot,
    )


_ROLES = {
    "joint_states": "the measured joint angles, velocities and torques",
    "commands": "the commanded torques",
    "motor_states": "the motor angles",
}


@dataclass(frozen=True)
class _States:
    stamps: np.ndarray  # (n,) int64 ns
    position: np.ndarray  # (n, N)
    velocity: np.ndarray | None
    effort: np.ndarray | None


def _joint_states(
    reader: "AnyReader", connection: "Connection", joints: tuple[str, ...]
) -> _States:
    """Every message of one JointState topic, its joints in the arm's order (`joints`) if so
    named, else in the order the messages list them (as many as the arm has)."""
    stamps, rows = [], {"position": [], "velocity": [], "effort": []}
    order = None
    for _, time, raw in reader.messages(connections=[connection]):
        message = reader.deserialize(raw, connection.msgtype)
        if order is None:
            names = list(message.name)
            if len(names) != len(joints):
                raise BadLog(
                    f"{connection.topic} names {len(names)} joints, the arm has {len(joints)} "
                    f"({', '.join(joints)}): --robot names the arm"
                )
            order = (
                [names.index(joint) for joint in joints]
                if set(names) == set(joints)
                else list(range(len(names)))
            )
        stamp = message.header.stamp
        stamps.append(
            stamp.sec * 1_000_000_000 + stamp.nanosec if stamp.sec or stamp.nanosec else time
        )
        for field, values in rows.items():
            array = np.asarray(getattr(message, field), dtype=float)
            values.append(array[order] if len(array) == len(order) else None)
    if not stamps:
        raise BadLog(f"{connection.topic} has no messages")
    columns = {}
    for field, values in rows.items():
        columns[field] = None if any(v is None for v in values) else np.array(values)
    if columns["position"] is None:
        raise BadLog(f"{connection.topic} has messages without positions")
    return _States(np.asarray(stamps, dtype=np.int64), **columns)


def _step(name: str, topic: str, stamps: np.ndarray) -> int:
    """How many messages make one 2 ms tick: 1 at 500 Hz, k at k × 500 Hz; else refused."""
    if len(stamps) < 2 or np.any(np.diff(stamps) <= 0):
        raise BadLog(f"{name!r}: {topic}'s stamps do not increase")
    period = float(np.median(np.diff(stamps)))
    step = round(CONTROL_PERIOD_NS / period)
    if step < 1 or abs(step * period - CONTROL_PERIOD_NS) > 0.02 * CONTROL_PERIOD_NS:
        raise BadLog(
            f"{name!r}: {topic} is at {1e9 / period:.4g} Hz; the plant's rate is "
            f"{1 / CONTROL_PERIOD:g} Hz (record at it, or at a multiple of it)"
        )
    return step


def _ticks(name: str, topic: str, stamps: np.ndarray, step: int) -> np.ndarray:
    """The indices of the messages one per tick: every `step`-th; a gap is refused."""
    gaps = np.diff(stamps) > (1 + JITTER) * CONTROL_PERIOD_NS / step
    if gaps.any():
        first = int(np.argmax(gaps))
        missing = (stamps[first + 1] - stamps[first]) / 1e6
        at = (stamps[first] - stamps[0]) / 1e9
        raise BadLog(
            f"{name!r}: {topic} has a gap of {missing:.3g} ms at t = {at:.3f} s: calibration "
            "needs every tick (record without drops, or cut the episode there)"
        )
    return np.arange(0, len(stamps), step)


def _no_jumps(
    name: str, topic: str, q: np.ndarray, stamps: np.ndarray, robot: str = DEFAULT_ROBOT
) -> None:
    if not np.isfinite(q).all():
        raise BadLog(f"{name!r}: {topic} has positions that are not numbers")
    arm = robot_of(robot)
    bound = JUMP * np.asarray(arm.limits.speed) * CONTROL_PERIOD
    moves = np.abs(np.diff(q, axis=0)) > bound
    if moves.any():
        tick, joint = np.argwhere(moves)[0]
        size = abs(q[tick + 1, joint] - q[tick, joint])
        at = (stamps[tick + 1] - stamps[0]) / 1e9
        raise BadLog(
            f"{name!r}: {topic} jumps {size:.3g} rad in {arm.joint_names[joint]} at "
            f"t = {at:.3f} s, more than {JUMP:g} times its speed limit allows in a tick"
        )


def _aligned(name: str, topic: str, states: _States, stamps: np.ndarray) -> _States:
    """`states` at the joint states' ticks: the message stamped nearest each, within a quarter
    period; refused where there is none."""
    index = np.clip(np.searchsorted(states.stamps, stamps), 1, len(states.stamps) - 1)
    before, after = states.stamps[index - 1], states.stamps[index]
    index = np.where(np.abs(stamps - before) <= np.abs(after - stamps), index - 1, index)
    off = np.abs(states.stamps[index] - stamps) > JITTER * CONTROL_PERIOD_NS
    if off.any():
        at = (stamps[int(np.argmax(off))] - stamps[0]) / 1e9
        raise BadLog(
            f"{name!r}: {topic} has no message within {JITTER * CONTROL_PERIOD * 1e3:g} ms of "
            f"the joint states' tick at t = {at:.3f} s"
        )
    velocity, effort = (None if a is None else a[index] for a in (states.velocity, states.effort))
    return _States(stamps, states.position[index], velocity, effort)
