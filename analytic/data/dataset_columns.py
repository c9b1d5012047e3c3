"""The dataset's columns: every column of its three tables with its unit and description (kept
in each Parquet field's metadata), the per-tick signals by joint and axis, the acceleration fit
and calm threshold they document, and the format's version.

A dataset is of one arm: its per-joint columns are named by that arm's joints (`q_A1` for the
iiwa 14, `q_shoulder_pan_joint` for the UR5e), as many as it has, and every table's Parquet
metadata names the robot (`robot`) and its joints (`joint_names`, JSON). A dataset from before
them is the iiwa 14's (`ROBOT_BEFORE`)."""

import json
from collections.abc import Sequence

import pyarrow as pa

from gainfarm.schemas.limits import Limits
from gainfarm.schemas.robot import DEFAULT_ROBOT, JOINT_NAMES

# 2: run-id episode ids, trajectories.parquet, qdd, split, units; 3: u_motor; 4: qdd_sg, calm;
# 5: the *_variants splits
DATASET_VERSION = "5"
TRAJECTORY_ID_DIGITS = 12

# qdd_sg: the second derivative of a Savitzky-Golay fit of q, a cubic over SG_WINDOW ticks
# (42 ms) centred on each tick, within the episode. The forward difference of q̇ (itself a
# 3-tick difference of quantised, noisy angles) leaves the true model of the realistic plant a
# test nMSE of 0.093; this fit, 0.0011. Measured on 51 test episodes of a tuned front on the
# FRI plant: windows 11, 21, 31, 51 gave 0.0031, 0.0011, 0.0016, 0.0059 with a cubic, and a
# quintic did no better under 51 ticks (docs/dataset.md, "Two accelerations").
SG_WINDOW = 21
SG_ORDER = 3
# An episode is calm if it ran to its end and its command keeps out of the band above the arm's
# lowest elastic mode: the chatter measure (schemas.objectives) within the default safety
# limit's 2 % of the torque limit. The smooth controllers measured put at most 0.8 % there, the
# chattering ones 50 % to 99 % (schemas.limits).
CALM_CHATTER = Limits().chatter
# The arm of a dataset whose metadata names none (written before any other arm could be): the
# iiwa 14, with its joints A1..A7.
ROBOT_BEFORE, JOINTS_BEFORE = DEFAULT_ROBOT, JOINT_NAMES
ROBOT_KEY, JOINTS_KEY = "robot", "joint_names"  # the Parquet schema metadata naming the arm

# Per-tick signals: name → (unit, what it is). Joint signals get _<joint> (_A1.._A7 on the iiwa
# 14), Cartesian _x.._z.
JOINT_SIGNALS = {
    "q": ("rad", "link-side joint position, as the encoders measured it"),
    "qd": ("rad/s", "link-side joint velocity, as measured"),
    "qdd": (
        "rad/s^2",
        "link-side acceleration (qd[k+1] - qd[k]) / control period, within the episode: what "
        "row k's command produced; NaN on an episode's last tick",
    ),
    "qdd_sg": (
        "rad/s^2",
        f"link-side acceleration at tick k: second derivative of a Savitzky-Golay fit of q "
        f"(order {SG_ORDER}, {SG_WINDOW} ticks centred on k), within the episode; NaN in an "
        f"episode shorter than {SG_WINDOW} ticks",
    ),
    "tau": ("N*m", "joint torque sensors' reading (the spring torque if the joints are elastic)"),
    "u": (
        "N*m",
        "the controller's torque command as the robot applied it (delayed, saturated) from tick "
        "k to k + 1; behind FRI without the robot's own gravity compensation",
    ),
    "u_motor": (
        "N*m",
        "torque the motors exerted from tick k to k + 1: u, plus behind FRI the robot's gravity "
        "model at its measured angles, saturated; what a model of the arm's dynamics predicts",
    ),
    "theta": ("rad", "motor-side angle, as measured (the link angle if the joints are rigid)"),
    "theta_d": ("rad/s", "motor-side velocity, as measured"),
    "q_des": ("rad", "reference joint position"),
    "qd_des": ("rad/s", "reference joint velocity"),
}
LOGGED_JOINT_SIGNALS = tuple(s for s in JOINT_SIGNALS if s not in ("qdd", "qdd_sg", "u_motor"))
CARTESIAN_SIGNALS = {
    "ee": ("m", "flange position, base frame"),
    "ee_des": ("m", "desired flange position, base frame"),
}
AXES = ("x", "y", "z")

# Every other column of the three tables: name → (unit, what it is). "" is no unit (ids, counts).
COLUMNS = {
    "episode_id": ("", "<first 8 hex digits of the run_id>-<job id> (-rerun- for reruns)"),
    "trajectory": ("", "the trajectory's kind"),
    "trajectory_id": ("", "short SHA-256 of the trajectory's canonical JSON spec"),
    "split": ("", "train, validation or test: by trajectory"),
    "t": ("s", "time since the episode started"),
    "run": ("", "the tuning run's directory name, or 'rerun'"),
    "run_id": ("", "the run_id (run.json) of the run the controller was tuned in"),
    "source": ("", "tuning: an episode of the tuning run; rerun: run again for the dataset"),
    "f_acc": ("m", "mean end-effector position error of this episode"),
    "f_t": ("(N*m)^2", "mean squared torque change per tick of this episode"),
    "diverged": ("", "the episode was stopped early"),
    "ticks": ("", "ticks in the episode"),
    "duration": ("s", "the trajectory's duration"),
    "trajectory_spec": ("", "the TrajectorySpec, JSON"),
    "model": ("", "the plant: PlantSpec, JSON"),
    "gravity_compensation": ("", "g(q_des) feed-forward was on"),
    "feedforward": ("", "SHA-256 of the learned inverse-dynamics feed-forward, if any"),
    "candidate_f_acc": ("m", "the controller's f_acc over its run's trajectory set"),
    "candidate_f_t": ("(N*m)^2", "the controller's f_t over its run's trajectory set"),
    "torque_step": ("1", "largest torque change in a tick, share of the joint's torque limit"),
    "saturated_fraction": ("1", "share of ticks with a joint at its torque limit"),
    "speed": ("1", "largest measured joint speed, share of its data-sheet limit"),
    "chatter": ("1", "RMS of the command above 10 Hz, share of the joint's torque limit"),
    "lag": ("rad", "largest RMS of a joint's measured angle less its reference's"),
    "within_limits": ("", "the controller keeps its run's safety limits on all its episodes"),
    "calm": ("", "the episode ran to its end without chatter (chatter within 0.02)"),
    "kind": ("", "the trajectory's kind"),
    "seed": ("", "which path of its kind (random, fourier; spiral, pyramid turned and mirrored)"),
    "center_x": ("m", "the Cartesian path's centre, base frame"),
    "center_y": ("m", "the Cartesian path's centre, base frame"),
    "center_z": ("m", "the Cartesian path's centre, base frame"),
    "size": ("m", "the Cartesian path's half-width"),
    "twist": ("rad", "amplitude of the flange's turn about the tool axis"),
    "turns": ("", "spiral only: turns"),
    "waypoints": ("", "random only: control points"),
    "harmonics": ("", "fourier only: harmonics per joint"),
    "spec": ("", "the TrajectorySpec, canonical JSON (sorted keys): what trajectory_id hashes"),
    "episodes": ("", "episodes of this trajectory in the dataset"),
}
GAINS = {"kp": ("N*m/rad", "proportional gain"), "kd": ("N*m*s/rad", "derivative gain")}


def column_unit(name: str, joints: Sequence[str] = JOINTS_BEFORE) -> tuple[str, str]:
    """A column's (unit, description), `joints` the dataset's arm's; KeyError for a column
    nobody documented. A joint's name may hold underscores (shoulder_pan_joint): the signal is
    the prefix that leaves a joint's name."""
    if name in COLUMNS:
        return COLUMNS[name]
    for joint in joints:
        signal = name.removesuffix(f"_{joint}")
        if signal != name and signal in JOINT_SIGNALS:
            return JOINT_SIGNALS[signal]
        if signal != name and signal in GAINS:
            return GAINS[signal]
    signal, _, part = name.rpartition("_")
    if part in AXES and signal in CARTESIAN_SIGNALS:
        return CARTESIAN_SIGNALS[signal]
    raise KeyError(f"column {name!r} has no unit")


def arm_metadata(robot: str, joints: Sequence[str]) -> dict[str, str]:
    """The schema metadata naming a dataset's arm (ROBOT_KEY, JOINTS_KEY)."""
    return {ROBOT_KEY: robot, JOINTS_KEY: json.dumps(list(joints))}


def with_units(
    table: pa.Table, metadata: dict[str, str], joints: Sequence[str] = JOINTS_BEFORE
) -> pa.Table:
    """`table` with every field's unit and description in its metadata, and `metadata` (the
    control period, the dataset's version, its arm: `arm_metadata`...) in the schema's: Parquet
    keeps both. `joints` are the arm's, which name its per-joint columns."""
    fields = []
    for field in table.schema:
        unit, description = column_unit(field.name, joints)
        fields.append(field.with_metadata({"unit": unit, "description": description}))
    schema = pa.schema(fields, metadata=metadata)
    return pa.Table.from_arrays(table.columns, schema=schema)
