"""What the system layer is asked to move: a Cartesian flange path, or a joint-space excitation."""

from enum import StrEnum
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

CONTROL_PERIOD = 0.002  # s: the paper's 500 Hz loop
CONTROL_PERIOD_NS = 2_000_000  # the same, in the integer nanoseconds of log times
MIN_DURATION = 0.1  # s: shorter is not a trajectory, just a jolt
MAX_DURATION = 120.0  # s: the paper uses 3-6 s; longer is certainly a typo
MAX_TWIST = 1.5  # rad: A7 turns ±175°, and it also absorbs A1's swing about the vertical

Coordinate = Annotated[float, Field(allow_inf_nan=False)]

# A kind is a name of the gainfarm.trajectories plug-in group: the built-in ones below, or a
# plug-in's (worker/trajectories/: a Kind, or a Cartesian path function). The contract checks
# the name's form only; a worker without the plug-in refuses the job, naming it. The pattern is
# gainfarm.plugins.NAME_PATTERN's (the contract imports nothing of the project; a test keeps
# the two equal): a name becomes part of job ids and file names.
KIND_PATTERN = r"^[a-z][a-z0-9_-]{0,31}$"


class TrajectoryKind(StrEnum):
    """The built-in kinds."""

    spiral = "spiral"  # a conical helix, widening from the centre
    random = "random"  # a smooth B-spline shaped by seeded random control points
    pyramid = "pyramid"  # straight edges of a square pyramid, resting at every corner
    fourier = "fourier"  # per-joint finite Fourier series: the identification standard


class TrajectorySpec(BaseModel):
    """A motion of the arm in the robot's base frame, lasting `duration` seconds, rest to rest.

    The Cartesian kinds (spiral, random, pyramid, and a plug-in's) move the flange along a path
    around `center` with the tool axis pointing down and a `twist` about it; the pyramid rests at
    every corner.
    The fourier kind moves every joint by a seeded finite Fourier series around the ready
    posture, one period per episode (Swevers et al. 1997; at 13.33 s its base frequency is the
    0.075 Hz of Gaz et al. 2019). worker/reference.py keeps every kind within the robot's joint
    ranges, speed and acceleration limits, and refuses a Cartesian path too fast for them.
    The defaults (a 16 cm path centred at (0.55, 0, 0.35) m, twist 0.4 rad) keep the paper's
    3-6 s paths feasible: for seeds 0-15 the spiral needs 2.7 s, the pyramid 2.8 s at most; the
    random kind 2.3 s at most for seeds 0-9 (and 3 s for 99 of seeds 0-99).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: str = Field(
        TrajectoryKind.spiral.value,
        pattern=KIND_PATTERN,
        description="a built-in kind (spiral, random, pyramid, fourier) or a plug-in's, installed "
        "on the workers (gainfarm.trajectories entry points)",
    )
    duration: float = Field(5.0, ge=MIN_DURATION, le=MAX_DURATION, allow_inf_nan=False)
    seed: int = Field(
        0,
        ge=0,
        lt=2**63,  # as a job's other numbers, of a bounded length: a submission's size is bounded
        description="which path of its kind: draws the random kind's control points and the "
        "fourier kind's series, turns and mirrors the spiral and the pyramid about their centre "
        "(seed 0: unturned)",
    )
    center: tuple[Coordinate, Coordinate, Coordinate] = Field(
        (0.55, 0.0, 0.35), description="m, the Cartesian path's centre; fourier ignores it"
    )
    size: float = Field(
        0.08,
        gt=0,
        le=0.5,
        allow_inf_nan=False,
        description="m, the Cartesian path's half-width; fourier ignores it",
    )
    turns: float = Field(2.0, gt=0, le=20, allow_inf_nan=False, description="spiral only")
    waypoints: int = Field(6, ge=2, le=50, description="random only: its control points")
    twist: float = Field(
        0.4,
        ge=0,
        le=MAX_TWIST,
        allow_inf_nan=False,
        description="rad, amplitude of the flange's turn about the tool axis, twist·sin(2πs) "
        "over the path's progress s; Cartesian kinds only (fourier ignores it)",
    )
    harmonics: int = Field(
        5, ge=2, le=10, description="fourier only: harmonics per joint (two at least, to rest)"
    )

    @property
    def ticks(self) -> int:
        """Control ticks in the episode: one at t = 0 and one every 2 ms up to `duration`."""
        return round(self.duration / CONTROL_PERIOD) + 1
