"""An arm's recorded episodes, as calibration reads them: what a robot-side log holds.

A real arm reports its joint angles, velocities and torque sensors (`sensor_msgs/JointState` on
/joint_states), the torques its controller commanded (/joint_commands) and, if it can, its motor
angles (/motor_states). gainfarm's own episode logs hold the same channels, and their metadata
names the controller that ran (its gains, its reference, the side it fed back, the interface):
what a user of a real arm knows too. The plant's numbers in that metadata are never read: a
hidden arm's log must not tell calibration the answer.

One thing differs: gainfarm logs the command as the motors applied it (after the delay), a real
arm's client logs what it sent. The PD law and the logged measurements give back what was sent.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, read_episode
from gainfarm.schemas.trajectory import CONTROL_PERIOD, TrajectorySpec


class BadLog(ValueError):
    """A log calibration cannot use: the message names the file and why, in one line."""


@dataclass(frozen=True)
class Recording:
    """One episode of an arm, every array (n, 7) at the 500 Hz control rate, SI units."""

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

    @property
    def ticks(self) -> int:
        return len(self.q)

    @property
    def feedback(self) -> tuple[np.ndarray, np.ndarray]:
        """The angles and velocities the robot's controller read."""
        if self.fed_back == "motor" and self.theta is not None and self.theta_d is not None:
            return self.theta, self.theta_d
        return self.q, self.qd


def read_recording(path: Path) -> Recording:
    """One episode from a gainfarm MCAP log; BadLog in one line naming the file."""
    try:
        log = read_episode(path)
    except OSError as error:
        raise BadLog(f"{str(path)!r}: cannot read: {error.strerror}") from None
    except NotAnEpisodeLog as error:
        raise BadLog(f"{str(path)!r}: {error}") from None
    spec = log.metadata.spec
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
    side = spec.model.feedback
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
    )


MIN_TICKS = 500  # 1 s: shorter says little beyond its start
