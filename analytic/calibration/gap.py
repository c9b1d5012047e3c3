"""The gap between an arm and a plant: its logged episodes replayed through the plant.

A replay runs the logged episode's controller (its gains, its reference) on the plant, closed
loop, as the arm ran it; the simulation error is the RMS over ticks of the replayed measurement
less the logged one, per joint: of the joint angle q and of the joint torque. Beside it, the
episode's objectives as the plant predicts them and as the arm's log shows them.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from gainfarm.analytic.calibration.logs import BadLog, Recording
from gainfarm.models import robot_of
from gainfarm.schemas.controller import Controller
from gainfarm.schemas.documents import BadDocument, load_json, read_bounded
from gainfarm.schemas.episode import EpisodeMetadata, EpisodeSpec, Scores
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD, TrajectorySpec
from gainfarm.worker.reference import flange_positions, reference_for


@dataclass(frozen=True)
class Gap:
    """One logged episode against its replay on one plant."""

    q: np.ndarray  # (N,) RMS of q error per joint, rad
    torque: np.ndarray  # (N,) RMS of joint torque error, N·m
    f_acc: float  # the replay's (the plant's prediction), m
    f_t: float  # (N·m)²
    logged_f_acc: float  # the arm's
    logged_f_t: float

    @property
    def f_acc_error(self) -> float:
        """The prediction's error as a share of what the arm did."""
        return abs(self.f_acc - self.logged_f_acc) / self.logged_f_acc


def gap(logged: EpisodeLog, logged_scores: Scores, replay: EpisodeLog, scores: Scores) -> Gap:
    """How far `replay` (the episode on a plant) is from `logged` (the arm's)."""
    n = min(logged.ticks, replay.ticks)  # a replay that diverged stops early: its ticks count
    return Gap(
        q=_rms(replay.q[:n] - logged.q[:n]),
        torque=_rms(replay.tau[:n] - logged.tau[:n]),
        f_acc=scores.f_acc,
        f_t=scores.f_t,
        logged_f_acc=logged_scores.f_acc,
        logged_f_t=logged_scores.f_t,
    )


def _rms(error: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.square(error), axis=0))


def pooled(gaps: Sequence[Gap], attribute: str) -> np.ndarray:
    """Per joint RMS over episodes (each episode weighted alike)."""
    return np.sqrt(np.mean([np.square(getattr(g, attribute)) for g in gaps], axis=0))


# --- a robot's bags: which controller and reference ran them ------------------------------------

# A bag follows a reference when its angles stay this close to it (RMS over its ticks, rad): a
# few centimetres at the flange, what the factory gains and the excitations' track within.
FOLLOWS = 0.05


@dataclass(frozen=True)
class Played:
    """A controller and a reference a robot played: what replays a bag of it."""

    name: str
    gains: PDGains
    trajectory: TrajectorySpec


# An excitation's reference is sampled at every tick: a 60 s one is some MB of JSON.
MAX_PLAYED_BYTES = 64 << 20


def read_played(path: Path) -> list[Played]:
    """What a file says was played: an excitation of `analytic excite` (its reference and gains)
    or a controller of `analytic export` (its gains on each of its run's trajectories); BadLog in
    one line."""
    try:
        document = load_json(read_bounded(Path(path), MAX_PLAYED_BYTES))
    except OSError as error:
        raise BadLog(f"--played: cannot read {str(path)!r}: {error.strerror}") from None
    except BadDocument as error:
        raise BadLog(f"--played: {str(path)!r}: {error}") from None
    except ValueError:
        raise BadLog(f"--played: {str(path)!r} is not JSON") from None
    name = Path(path).stem
    try:
        if (
            isinstance(document, dict)
            and document.get("format") == Controller.model_fields["format"].default
        ):
            controller = Controller.model_validate(document)
            return [
                Played(f"{name}[{k}]", controller.gains, trajectory)
                for k, trajectory in enumerate(controller.source.trajectories)
            ]
        if isinstance(document, dict) and {"trajectory", "gains"} <= document.keys():
            return [
                Played(
                    name,
                    PDGains.model_validate(document["gains"]),
                    TrajectorySpec.model_validate(document["trajectory"]),
                )
            ]
    except ValidationError as error:
        raise BadLog(f"--played: {str(path)!r}: {error.errors()[0]['msg']}") from None
    raise BadLog(
        f"--played: {str(path)!r} is neither an excitation (`analytic excite`) nor a controller "
        "(`analytic export`)"
    )


def played_by(recording: Recording, played: Sequence[Played]) -> Played:
    """Which of `played` the recording's angles follow (the nearest reference, RMS); BadLog if
    none within FOLLOWS."""
    if not played:
        raise BadLog(
            f"{recording.name!r}: a robot's bag names no controller: say what was played "
            "(--played EXCITATION.json or CONTROLLER.json)"
        )
    distances = []
    for item in played:
        reference = reference_for(item.trajectory, recording.robot)
        n = min(len(reference.q), recording.ticks)
        distances.append(float(np.sqrt(np.mean((recording.q[:n] - reference.q[:n]) ** 2))))
    best = int(np.argmin(distances))
    if distances[best] > FOLLOWS:
        raise BadLog(
            f"{recording.name!r} follows none of --played's references (the nearest, "
            f"{played[best].name}, is {distances[best]:.3g} rad RMS away)"
        )
    return played[best]


def as_episode(recording: Recording, played: Played, nominal: PlantSpec) -> EpisodeLog:
    """The bag as an episode log of what was played: its reference and flange path beside the
    arm's (the flange by the arm's kinematics from its angles), scored as any episode is. The
    commanded torque stands for the applied one: the objectives of torque change do not see the
    delay between them."""
    reference = reference_for(played.trajectory, nominal.robot)
    arm = robot_of(nominal)
    n = min(len(reference.q), recording.ticks)
    spec = EpisodeSpec(gains=played.gains, trajectory=played.trajectory, plant=nominal)
    theta = recording.theta if recording.theta is not None else recording.q
    theta_d = recording.theta_d if recording.theta_d is not None else recording.qd
    return EpisodeLog(
        t=np.arange(n) * CONTROL_PERIOD,
        q=recording.q[:n],
        qd=recording.qd[:n],
        tau=recording.tau[:n],
        u=recording.command[:n],
        theta=theta[:n],
        theta_d=theta_d[:n],
        q_des=np.asarray(reference.q[:n]),
        qd_des=np.asarray(reference.qd[:n]),
        ee=flange_positions(recording.q[:n], nominal.robot),
        ee_des=np.asarray(reference.ee[:n]),
        metadata=EpisodeMetadata(
            spec=spec,
            ticks_planned=len(reference.q),
            ticks_run=n,
            torque_limits=arm.limits.torque,
            joint_names=arm.joint_names,
            speed_limits=arm.limits.speed,
            diverged=False,
            versions={"recorded": recording.name},
        ),
    )
