"""The wire contract: every message, file layout and key every other package agrees on."""

from gainfarm.schemas.episode import EpisodeMetadata, EpisodeSpec, Scores
from gainfarm.schemas.episode_log import CHANNELS, EpisodeLog
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import JOINT_NAMES, N_JOINTS, TORQUE_LIMITS, PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD, TrajectoryKind, TrajectorySpec

__all__ = [
    "CHANNELS",
    "CONTROL_PERIOD",
    "JOINT_NAMES",
    "N_JOINTS",
    "TORQUE_LIMITS",
    "EpisodeLog",
    "EpisodeMetadata",
    "EpisodeSpec",
    "PDGains",
    "PlantSpec",
    "Scores",
    "TrajectoryKind",
    "TrajectorySpec",
]
