"""The episode log: what one episode recorded, tick by tick, and the MCAP channels that carry it.

The channel contract (topics, ROS 2 message types, what each field holds) is part of the wire
contract: dataset consumers and tools such as ros2 bag, Foxglove and PlotJuggler depend on it.
schemas/README.md documents it for humans; this module is its single source of truth.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gainfarm.schemas.episode import EpisodeMetadata

JOINT_STATE = "sensor_msgs/msg/JointState"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"


@dataclass(frozen=True)
class Channel:
    topic: str
    message_type: str
    frame_id: str
    fields: tuple[tuple[str, str], ...]  # (message field, EpisodeLog attribute)


CHANNELS = (
    Channel(
        "/joint_states", JOINT_STATE, "", (("position", "q"), ("velocity", "qd"), ("effort", "tau"))
    ),
    Channel("/joint_commands", JOINT_STATE, "", (("effort", "u"),)),
    Channel("/motor_states", JOINT_STATE, "", (("position", "theta"), ("velocity", "theta_d"))),
    Channel("/joint_reference", JOINT_STATE, "", (("position", "q_des"), ("velocity", "qd_des"))),
    Channel("/ee/actual", POINT_STAMPED, "world", (("point", "ee"),)),
    Channel("/ee/desired", POINT_STAMPED, "world", (("point", "ee_des"),)),
)
METADATA_NAME = "gainfarm.episode"

# Channels made from the log for ROS 2 tools (Foxglove's 3D panel, rviz, ros2 bag play), not
# columns of it: the readers ignore them. /robot_description holds the arm's URDF once, at the
# first tick, latched (transient local, as robot_state_publisher offers it); /tf the arm's links,
# each from its parent, every TF_EVERY ticks and at the last. Both come from a RobotDescription
# the writer is given (the iiwa's is models/urdf.py's `description()`).
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
STRING = "std_msgs/msg/String"
TF_TOPIC = "/tf"
DESCRIPTION_TOPIC = "/robot_description"
# 50 Hz: smooth to the eye (a screen shows 60 frames a second, `analytic replay` 30), a tenth of
# the full rate's bytes, and nothing is lost to a plot: /joint_states has every tick.
TF_EVERY = 10


@dataclass(frozen=True)
class Frame:
    """One parent→child transform of the arm's tree, as /tf names it: its translation is fixed,
    its rotation turns with the joint angles."""

    parent: str
    child: str
    translation: tuple[float, float, float]  # m, in the parent's frame


@dataclass(frozen=True)
class RobotDescription:
    """What ROS tools need to draw the arm, given to the log's writer: the contract lays out the
    channels, the robot's model fills them in."""

    urdf: str  # /robot_description's text
    frames: tuple[Frame, ...]  # /tf's transforms, in the order of `rotations`' second axis
    # Joint angles (n, joints) -> (n, len(frames), 4): each frame's rotation at each row, x y z w.
    rotations: Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class EpisodeLog:
    """One row per 2 ms control tick. Joint arrays are (n, joints), one column per joint its
    metadata names (EpisodeMetadata.joint_names); positions (n, 3); SI units."""

    t: np.ndarray  # simulated time since the episode started, s
    q: np.ndarray  # measured link-side joint positions, rad
    qd: np.ndarray  # measured link-side joint velocities, rad/s
    tau: np.ndarray  # measured joint torques (the torque sensors: spring torque if elastic), N·m
    u: np.ndarray  # torque commands as applied to the motors (delayed, saturated), N·m
    theta: np.ndarray  # measured motor-side angles, rad (the link angles if rigid)
    theta_d: np.ndarray  # measured motor-side velocities, rad/s
    q_des: np.ndarray  # reference joint positions, rad
    qd_des: np.ndarray  # reference joint velocities, rad/s
    ee: np.ndarray  # flange position in the world frame, m
    ee_des: np.ndarray  # desired flange position, m
    metadata: EpisodeMetadata

    @property
    def ticks(self) -> int:
        return len(self.t)
