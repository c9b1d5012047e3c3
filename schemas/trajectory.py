"""What the system layer is asked to draw with the end effector."""

from enum import StrEnum
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

CONTROL_PERIOD = 0.002  # s: the paper's 500 Hz loop
CONTROL_PERIOD_NS = 2_000_000  # the same, in the integer nanoseconds of log times
MIN_DURATION = 0.1  # s: shorter is not a trajectory, just a jolt
MAX_DURATION = 120.0  # s: the paper uses 3-6 s; longer is certainly a typo

Coordinate = Annotated[float, Field(allow_inf_nan=False)]


class TrajectoryKind(StrEnum):
    spiral = "spiral"  # a conical helix, widening from the centre
    random = "random"  # a smooth spline through seeded random waypoints
    pyramid = "pyramid"  # straight edges of a square pyramid: sharp corners, high accelerations


class TrajectorySpec(BaseModel):
    """A Cartesian end-effector path in the robot's base frame, traversed in `duration` seconds.

    Every kind starts and ends at rest (minimum-jerk timing along the path); the pyramid's
    corners are still sharp because the direction changes there at speed.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: TrajectoryKind = TrajectoryKind.spiral
    duration: float = Field(5.0, ge=MIN_DURATION, le=MAX_DURATION, allow_inf_nan=False)
    seed: int = Field(0, ge=0, description="only the random kind draws from it")
    center: tuple[Coordinate, Coordinate, Coordinate] = (0.55, 0.0, 0.4)
    size: float = Field(0.12, gt=0, le=0.5, allow_inf_nan=False, description="metres")
    turns: float = Field(2.0, gt=0, le=20, allow_inf_nan=False, description="spiral only")
    waypoints: int = Field(6, ge=2, le=50, description="random only")

    @property
    def ticks(self) -> int:
        """Control ticks in the episode: one at t = 0 and one every 2 ms up to `duration`."""
        return round(self.duration / CONTROL_PERIOD) + 1
