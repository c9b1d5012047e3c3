"""Excitation references to record on a real arm, checked safe before anyone plays them.

A twin is calibrated from episodes of the real arm (`analytic calibrate`; any gainfarm.robots
arm, the iiwa 14 by default); `analytic excite` writes what the robot side plays to record them:
fourier excitations (the identification standard, worker/reference.py: every joint moves, rest
to rest, within the arm's published limits, about its home posture) and the PD gains to track
them with. Pure: numbers in; the checks, the files' bytes and the
README's text out. The command writes them.

What is checked for each excitation, before anything is written:

- its sampled reference stays within the data sheet's joint ranges, speeds and accelerations
  (the robot's `limits`), and starts and ends at rest: the fourier
  kind is built that way, checked here anyway, since a real arm will follow it;
- it moves every joint by MIN_SPAN at least: a short fourier reference shrinks into the
  acceleration limits until it excites nothing;
- the controller's closed loop, linearised along it (worker.stability), is stable on the nominal
  plant and on VARIANTS plants drawn from the uncertainty ranges: a twin is not calibrated yet,
  so the gains must hold on any plant the ranges allow.
"""

import io
import json
import re
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from string import Template

import numpy as np
from mcap.writer import Writer
from rosbags.typesys import Stores, get_typestore

from gainfarm.analytic.data.arm import title
from gainfarm.models import plant_preset, resolve, robot_of
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.mcap_episode import schema_text
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec, Robot
from gainfarm.schemas.trajectory import (
    CONTROL_PERIOD,
    CONTROL_PERIOD_NS,
    TrajectoryKind,
    TrajectorySpec,
)
from gainfarm.worker.ik import UnreachablePath
from gainfarm.worker.reference import InfeasibleReference, Reference, reference_for
from gainfarm.worker.stability import least_damping

# Peak to peak, rad: a joint that moves less says nothing of its dynamics. The fourier kind
# reaches it from 1.0-1.5 s (seeds 0-99; docs/calibration.md).
MIN_SPAN = 0.05
# Plants each excitation's stability is checked on besides the nominal one: a check of one
# excitation on 1 + 8 plants takes 0.1 s (10 ms a plant), so the count is not cost-bound;
# 8 per excitation, each excitation drawing its own, is 80 distinct plants for the default 10.
VARIANTS = 8
# At rest: |q̇| and |q̈| at the reference's ends, rad/s and rad/s² (the series gives 1e-15).
REST = 1e-6
# The gains to record with: the factory gains (the robot's default_gains) scaled down together,
# measured on the iiwa 14 (its DEFAULT_GAINS; another arm's default gains follow the same rule
# by torque class, and each excitation is checked stable on its own arm's plants). The factory
# gains themselves are not stable on every plant the shipped ranges allow: on the 10 s fourier
# excitations of seeds 0-99, each on the nominal plant and its 8 variants (900 loops), their
# least damping is ≤ 0 on 161, mostly variants with a two-tick delay or heavy rotors (an
# episode on one of them chatters: torque steps 4.5 times the nominal plant's). Scaled together
# (the ratio Kd/Kp kept: Kd alone lowered destabilises the elastic mode, docs/limits.md): × 0.5
# on 10 of the 900, × 0.3 on 3 (seeds 29, 33, 37; two of them a 250 Hz mode of A5's light
# rotor and its Coulomb friction, as unstable at × 0.01). × 0.3 has a mean flange error of
# 6-19 mm instead of 2-7 (seeds 0-1, three plants): calibration fits what the arm did, not
# what it was asked to do.
GAIN_SCALE = 0.3


def gains_for(robot: str = DEFAULT_ROBOT) -> PDGains:
    """The gains to record `robot`'s excitations with: its default gains × GAIN_SCALE."""
    factory = robot_of(robot).default_gains
    return PDGains(
        kp=tuple(round(GAIN_SCALE * gain, 9) for gain in factory.kp),
        kd=tuple(round(GAIN_SCALE * gain, 9) for gain in factory.kd),
    )


GAINS = gains_for()  # the iiwa 14's

TOPIC = "/joint_trajectory"
MESSAGE_TYPE = "trajectory_msgs/msg/JointTrajectory"
METADATA_NAME = "gainfarm_excitation"
NANOSECONDS = 1_000_000_000


class Unsafe(ValueError):
    """An excitation refused: `option` is the option to change, the message says why."""

    def __init__(self, option: str, message: str):
        super().__init__(message)
        self.option = option


@dataclass(frozen=True)
class Excitation:
    """One checked excitation: its trajectory, reference and stability margin."""

    index: int
    trajectory: TrajectorySpec
    reference: Reference
    gains: PDGains  # the controller it was checked with
    damping: float  # least damping ratio over the nominal plant and the variants
    plants: int  # how many plants that is over
    robot: str = DEFAULT_ROBOT  # the arm it is for

    @property
    def name(self) -> str:
        return name(self.index)

    @property
    def span(self) -> np.ndarray:
        """(N,) each joint's peak-to-peak motion, rad."""
        return np.ptp(self.reference.q, axis=0)


def name(index: int) -> str:
    """The files' stem of excitation `index`: excitation-00, excitation-01, ..."""
    return f"excitation-{index:02d}"


def trajectory(duration: float, seed: int) -> TrajectorySpec:
    """The fourier excitation of `seed`, `duration` seconds long (ValidationError if out of
    TrajectorySpec's bounds)."""
    return TrajectorySpec(kind=TrajectoryKind.fourier.value, duration=duration, seed=seed)


def check_limits(
    index: int, trajectory: TrajectorySpec, reference: Reference, robot: str = DEFAULT_ROBOT
) -> None:
    """Unsafe, naming the joint and the limit, if the sampled reference leaves `robot`'s
    published limits or does not start and end at rest."""
    where = f"{name(index)} (seed {trajectory.seed})"
    arm = robot_of(robot)
    if reference.q.shape[1] != len(arm.joint_names):
        raise Unsafe("--robot", f"{where} moves {reference.q.shape[1]} joints, not {robot}'s")
    _check_range(where, reference.q, arm)
    for values, limits, what, unit in (
        (reference.qd, arm.limits.speed, "speed limit", "rad/s"),
        (reference.qdd, arm.limits.acceleration, "acceleration limit", "rad/s²"),
    ):
        peak = np.abs(values).max(axis=0)
        over = peak / np.asarray(limits)
        joint = int(np.argmax(over))
        if not over[joint] <= 1.0:  # a NaN is refused too (argmax finds the first)
            raise Unsafe(
                "--seed",
                f"{where} leaves {robot}'s published limits: {arm.joint_names[joint]} reaches "
                f"{peak[joint]:.3f} {unit}, beyond its {what} of ±{limits[joint]:.3f} {unit}",
            )
    for tick, end in ((0, "start"), (-1, "end")):
        moving = max(np.abs(reference.qd[tick]).max(), np.abs(reference.qdd[tick]).max())
        if moving > REST:
            raise Unsafe("--seed", f"{where} does not {end} at rest (|q̇|, |q̈| up to {moving:.3g})")


def _check_range(where: str, q: np.ndarray, arm: Robot) -> None:
    """Unsafe, naming the joint, if an angle leaves its joint's range (`limits.ranges`: ±its
    position limit, or its lowest and highest angle where they are not symmetric)."""
    lowest, highest = np.asarray(arm.limits.ranges, dtype=float).T
    below, above = lowest - q.min(axis=0), q.max(axis=0) - highest
    beyond = np.maximum(below, above)
    beyond = np.where(np.isnan(q).any(axis=0), np.inf, beyond)  # a NaN is refused too
    joint = int(np.argmax(beyond))
    if beyond[joint] > 0:
        low, high = arm.limits.ranges[joint]
        reached = q[:, joint][np.argmax(np.abs(q[:, joint] - (low + high) / 2))]
        range_text = f"±{high:.3f}" if low == -high else f"{low:.3f} to {high:.3f}"
        raise Unsafe(
            "--seed",
            f"{where} leaves {arm.name}'s published limits: {arm.joint_names[joint]} reaches "
            f"{reached:.3f} rad, beyond its joint range of {range_text} rad",
        )


def check_span(
    index: int, trajectory: TrajectorySpec, reference: Reference, robot: str = DEFAULT_ROBOT
) -> None:
    """Unsafe, naming --duration and the joint, if a joint moves less than MIN_SPAN."""
    span = np.ptp(reference.q, axis=0)
    joint = int(np.argmin(span))
    if span[joint] < MIN_SPAN:
        raise Unsafe(
            "--duration",
            f"{trajectory.duration:g} s is too short to excite "
            f"{robot_of(robot).joint_names[joint]}: "
            f"{name(index)} (seed {trajectory.seed}) moves it {span[joint]:.3f} rad peak to peak, "
            f"less than {MIN_SPAN:g} rad (a fourier reference shrinks into the acceleration limits "
            "as it gets shorter); give a longer --duration",
        )


def check_stable(
    index: int,
    gains: PDGains,
    trajectory: TrajectorySpec,
    reference: Reference,
    variants: Sequence[PlantSpec],
    ranges: str,
    robot: str = DEFAULT_ROBOT,
) -> float:
    """The least damping of `gains`' closed loop along the reference over `robot`'s nominal
    plant and `variants` (drawn from `ranges`, named so); Unsafe naming the plant if it is
    ≤ 0."""
    least = 1.0
    for number, plant in enumerate((nominal(robot), *variants)):
        damping = least_damping(
            EpisodeSpec(gains=gains, trajectory=trajectory, plant=plant), reference
        )
        if damping <= 0:
            where = f"{name(index)} (seed {trajectory.seed})"
            if number == 0:  # not the ranges' doing: the reference asks too much of the gains
                raise Unsafe(
                    "--seed",
                    f"the gains are unstable along {where} on the nominal plant "
                    f"(least damping {damping:+.4f})",
                )
            raise Unsafe(
                "--uncertainty",
                f"the gains are unstable along {where} on plant variant {number} of "
                f"{len(variants)} drawn from {ranges} (least damping {damping:+.4f}): not safe "
                "on an arm that may be that plant",
            )
        least = min(least, damping)
    return least


def nominal(robot: str = DEFAULT_ROBOT) -> PlantSpec:
    """The realistic plant of `robot`: the arm as documented, which the variants surround,
    every per-joint number written out (the ranges scale them)."""
    return resolve(plant_preset("realistic", robot))


def excitation(
    index: int,
    trajectory: TrajectorySpec,
    variants: Sequence[PlantSpec],
    ranges: str,
    gains: PDGains | None = None,
    robot: str = DEFAULT_ROBOT,
) -> Excitation:
    """Excitation `index` of `trajectory` on `robot`, every check passed (Unsafe otherwise);
    `gains` by default `gains_for(robot)`."""
    gains = gains_for(robot) if gains is None else gains
    try:
        reference = reference_for(trajectory, robot)
    except (UnreachablePath, InfeasibleReference) as error:  # its own guarantee of the ranges
        raise Unsafe("--seed", f"{name(index)} (seed {trajectory.seed}): {error}") from None
    check_limits(index, trajectory, reference, robot)
    check_span(index, trajectory, reference, robot)
    damping = check_stable(index, gains, trajectory, reference, variants, ranges, robot)
    return Excitation(index, trajectory, reference, gains, damping, 1 + len(variants), robot)


# --- the files ----------------------------------------------------------------------------------


def gains_json(gains: PDGains = GAINS) -> bytes:
    """controller.json: {"kp": [N], "kd": [N]}, as `worker episode --gains` reads it."""
    return (json.dumps(gains.model_dump(mode="json")) + "\n").encode()


def document(excitation: Excitation) -> dict[str, object]:
    """excitation-NN.json's object: what it is, then the reference, one N-list per tick."""
    reference = excitation.reference
    robot = robot_of(excitation.robot)
    return {
        "trajectory": excitation.trajectory.model_dump(mode="json"),
        "control_period": CONTROL_PERIOD,
        "robot": robot.name,
        "joint_names": list(robot.joint_names),
        "gains": excitation.gains.model_dump(mode="json"),
        "t": reference.t.tolist(),
        "positions": reference.q.tolist(),
        "velocities": reference.qd.tolist(),
        "accelerations": reference.qdd.tolist(),
    }


def document_json(excitation: Excitation) -> bytes:
    # Compact: 2 MB for 10 s (Python's float repr round-trips every float64 exactly).
    return (json.dumps(document(excitation), separators=(",", ":")) + "\n").encode()


def trajectory_mcap(excitation: Excitation) -> bytes:
    """The reference as ONE trajectory_msgs/msg/JointTrajectory on /joint_trajectory (a point
    per tick, time_from_start its tick time in whole nanoseconds), CDR-encoded, in an MCAP file
    of the ros2 profile that any MCAP reader and ROS 2 decoder reads. Its metadata record names
    the trajectory."""
    store = get_typestore(Stores.ROS2_HUMBLE)  # the episode logs' (schemas/mcap_episode.py)
    types = store.types
    reference = excitation.reference
    point = types["trajectory_msgs/msg/JointTrajectoryPoint"]
    duration = types["builtin_interfaces/msg/Duration"]
    no_effort = np.zeros(0)
    points = [
        point(
            positions=reference.q[tick],
            velocities=reference.qd[tick],
            accelerations=reference.qdd[tick],
            effort=no_effort,
            time_from_start=duration(
                sec=tick * CONTROL_PERIOD_NS // NANOSECONDS,
                nanosec=tick * CONTROL_PERIOD_NS % NANOSECONDS,
            ),
        )
        for tick in range(len(reference.t))
    ]
    # Stamp 0: a trajectory controller starts a message stamped 0 on receipt.
    header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""
    )
    joints = list(robot_of(excitation.robot).joint_names)
    message = types[MESSAGE_TYPE](header=header, joint_names=joints, points=points)
    data = bytes(store.serialize_cdr(message, MESSAGE_TYPE))
    out = io.BytesIO()
    writer = Writer(out)
    writer.start(profile="ros2", library="gainfarm")
    schema = writer.register_schema(
        name=MESSAGE_TYPE, encoding="ros2msg", data=schema_text(MESSAGE_TYPE).encode()
    )
    channel = writer.register_channel(topic=TOPIC, message_encoding="cdr", schema_id=schema)
    writer.add_message(channel_id=channel, log_time=0, data=data, publish_time=0, sequence=0)
    writer.add_metadata(
        METADATA_NAME,
        {
            "trajectory": excitation.trajectory.model_dump_json(),
            "control_period": repr(CONTROL_PERIOD),
            "robot": excitation.robot,
        },
    )
    writer.finish()
    return out.getvalue()


README = Template("""\
# Excitation episodes for calibrating a twin of your $arm

Written by `$command`: $count fourier excitations of $duration s each, to play and record on
the real arm. `analytic calibrate` then fits a simulation twin to the recordings.

## The files

- `excitation-NN.json` (NN = 00 to $last): one reference at 500 Hz (every 2 ms), for joints
  $joints: `t` (s), and one $count_joints-list per tick of `positions` (rad), `velocities`
  (rad/s) and
  `accelerations` (rad/s²); `trajectory` is the fourier trajectory it samples (seed $first + NN),
  `gains` the controller's.
- `excitation-NN.mcap`: the same reference as one ROS 2 `trajectory_msgs/msg/JointTrajectory`
  message on `/joint_trajectory`, a point per tick, `time_from_start` its time.
- `controller.json`: the PD gains to play them with$which: Kp $kp N·m/rad,
  Kd $kd N·m·s/rad ($joints).

## What to record

For each excitation:

1. Bring the arm to the reference's first point ($start) and let it come to rest.
2. Run the PD law at 500 Hz, u = Kp (q_des − q) + Kd (q̇_des − q̇) per joint, on the measured
   joint angles q (q̇ is the mean of the last $window differences of q over 2 ms, as in the
   simulation), in $interface.
3. Play the reference from its first point to its last, one point per tick: it starts and ends
   at rest.
4. Record at 500 Hz, in a ROS 2 bag or an MCAP file (one per excitation), joints named
   $joints, as `sensor_msgs/JointState` messages:
   - `/joint_states`: position (rad), velocity (rad/s) and effort, the measured joint torque
     (N·m);
   - `/joint_commands`: effort, the commanded torque u: what the controller sent$on_top (N·m);
   - `/motor_states`: position, the motor-side angles (rad), if the arm reports them.

Then: `analytic calibrate LOG...$robot_option --out TWIN`, the recordings as LOG.

## What was checked

Each reference stays within the $arm's published joint ranges, speeds and accelerations,
starts and ends at rest, and moves every joint by $min_span rad at least ($span rad here). The
controller's closed loop, linearised at poses along each reference, is stable on the nominal
simulated plant and on $variants plants per excitation drawn from $ranges: its least damping
ratio is $damping ($where; 0 would be unstable). These are checks in simulation, not a
guarantee on your arm: record at hand of the enabling switch.
""")


# A Markdown block the README's wrapping leaves as it is (a heading), or a list item's marker.
_HEADING = re.compile(r"#")
_ITEM = re.compile(r"(\s*)(- |\d+\. )")
WIDTH = 96


def wrapped(text: str, width: int = WIDTH) -> str:
    """`text` (Markdown: headings, paragraphs, list items) with every paragraph and item
    refilled to `width`, continuation lines indented under the item's text."""
    blocks: list[list[str]] = []
    for line in text.splitlines():
        if not line.strip():
            blocks.append([])
        elif _HEADING.match(line) or _ITEM.match(line) or not blocks or not blocks[-1]:
            blocks.append([line])
        else:
            blocks[-1].append(line.strip())
    out = []
    for block in blocks:
        if not block:
            out.append("")
        elif _HEADING.match(block[0]):
            out.append(block[0])
        else:
            item = _ITEM.match(block[0])
            first = item.group(0) if item else ""
            body = " ".join([block[0][len(first) :], *block[1:]])
            indent = " " * len(first)
            out.append(
                textwrap.fill(
                    body,
                    width,
                    initial_indent=first,
                    subsequent_indent=indent,
                    break_long_words=False,
                    break_on_hyphens=False,
                )
            )
    return "\n".join(out).strip("\n") + "\n"


def readme(excitations: Sequence[Excitation], command: str, ranges: str) -> str:
    """README.md: what the files are, how to record them, what was checked (the numbers)."""
    first, worst = excitations[0], min(excitations, key=lambda e: e.damping)
    gains = first.gains
    arm = robot_of(first.robot)
    joints = _joint_list(arm.joint_names)
    starts = {tuple(e.reference.q[0].round(4)) for e in excitations}
    start = (
        f"`positions[0]`, {joints} at " + ", ".join(f"{angle:g}" for angle in starts.pop()) + " rad"
        if len(starts) == 1
        else "each excitation's `positions[0]`"
    )
    interface = arm.torque_interface
    text = README.substitute(
        arm=title(arm.name),
        robot_option=f" --robot {arm.name}" * (arm.name != DEFAULT_ROBOT),
        joints=joints,
        count_joints=len(arm.joint_names),
        interface=(
            f"{interface.name}: the robot adds its own gravity compensation, u is the torque "
            "commanded on top of it"
            if interface.adds_gravity
            else f"{interface.name}: u is the whole torque commanded (the robot adds no gravity "
            "compensation of its own)"
        ),
        on_top=", on top of the robot's gravity compensation" * interface.adds_gravity,
        command=command,
        count=len(excitations),
        duration=f"{first.trajectory.duration:g}",
        last=name(excitations[-1].index).removeprefix("excitation-"),
        first=first.trajectory.seed,
        which=f", the factory gains × {GAIN_SCALE:g}" if gains == gains_for(arm.name) else "",
        kp=", ".join(f"{gain:g}" for gain in gains.kp),
        kd=", ".join(f"{gain:g}" for gain in gains.kd),
        start=start,
        window=nominal(arm.name).sensors.velocity_window,
        min_span=f"{MIN_SPAN:g}",
        span=f"{min(float(e.span.min()) for e in excitations):.2f}",
        variants=worst.plants - 1,
        ranges=ranges,
        damping=f"{worst.damping:+.3f} at least",
        where=f"{worst.name}",
    )
    return wrapped(text)


def _joint_list(joints: Sequence[str]) -> str:
    """The joints as the README names them: A1..A7, or each of them."""
    if all(joint == f"A{i}" for i, joint in enumerate(joints, start=1)):
        return f"{joints[0]}..{joints[-1]}"
    return ", ".join(joints)
