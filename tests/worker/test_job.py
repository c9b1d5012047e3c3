"""One job as a worker runs it: the scores it reports are the analytic side's scores of the very
log it made, bit for bit."""

import hashlib

import pytest

from gainfarm.models import plant_preset, robot_of
from gainfarm.models.dynamics import digest, rigid_prior, to_bytes
from gainfarm.schemas import EpisodeSpec, PDGains, TrajectorySpec
from gainfarm.schemas.episode import Scores
from gainfarm.schemas.mcap_episode import decode_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import IDEAL_PLANT, PLAIN_PLANT, PlantSpec
from gainfarm.schemas.wire import Job, JobStatus, Lease, Result, WireScores
from gainfarm.worker.job import execute, simulate
from tests.helpers import SOFT_GAINS, WEAK_GAINS, short_spec

RIGID_IDEAL = IDEAL_PLANT.model_copy(update={"joints": "rigid"})
FEEDFORWARD = to_bytes(rigid_prior(RIGID_IDEAL))

EPISODES = {
    "tracked": (short_spec(), None),
    "diverged": (
        EpisodeSpec(gains=WEAK_GAINS, trajectory=TrajectorySpec(duration=3.0), plant=PLAIN_PLANT),
        None,
    ),
    "feed-forward": (
        EpisodeSpec(
            gains=SOFT_GAINS,
            trajectory=TrajectorySpec(kind="fourier", duration=0.5, seed=4),
            plant=RIGID_IDEAL,
            feedforward=digest(FEEDFORWARD),
        ),
        lambda _: rigid_prior(RIGID_IDEAL),
    ),
}


@pytest.mark.parametrize("name", list(EPISODES))
def test_the_scores_of_the_episode_are_those_of_its_encoded_log_exactly(name: str) -> None:
    spec, model = EPISODES[name]
    outcome = simulate(spec, model)
    assert outcome.status == (JobStatus.diverged if name == "diverged" else JobStatus.ok)
    decoded = decode_episode(outcome.content)
    assert type(outcome.scores) is Scores
    assert outcome.scores == score(decoded)  # every float equal, not merely close
    assert outcome.scores.diverged == (name == "diverged")
    assert outcome.scores.ticks == decoded.ticks == decoded.metadata.ticks_run


UR5E = robot_of("ur5e")


def ur5e_spec(**plant: object) -> EpisodeSpec:
    """A short UR5e (6 joints) episode on its realistic plant, its default gains."""
    return EpisodeSpec(
        gains=UR5E.default_gains,
        trajectory=TrajectorySpec(kind="fourier", duration=0.5),
        plant=plant_preset("realistic", "ur5e").model_copy(update=plant),
    )


def test_a_six_joint_job_logs_its_arm_and_scores_as_its_log() -> None:
    outcome = simulate(ur5e_spec())
    assert outcome.status == JobStatus.ok, outcome.reason
    decoded = decode_episode(outcome.content)
    assert decoded.metadata.joint_names == UR5E.joint_names
    assert decoded.metadata.spec.plant.robot == "ur5e"
    assert decoded.metadata.torque_limits == UR5E.limits.torque
    assert decoded.q.shape == (decoded.ticks, 6)
    assert outcome.scores == score(decoded)


@pytest.mark.parametrize(
    ("spec", "reason"),
    [
        (
            EpisodeSpec(gains=UR5E.default_gains, plant=PlantSpec(robot="nosucharm")),
            "gainfarm.robots: no plug-in named 'nosucharm'",
        ),
        (
            short_spec().model_copy(update={"plant": PlantSpec(rotor_inertia=(0.1,) * 6)}),
            "rotor_inertia: 6 numbers for iiwa14's 7 joints",
        ),
        (
            short_spec().model_copy(update={"plant": PlantSpec(inertials="cad", robot="ur5e")}),
            "inertials: ur5e has no set 'cad'",
        ),
        (ur5e_spec(payload=6.0), "payload: 6 kg is beyond ur5e's rated 5 kg"),
        (
            ur5e_spec().model_copy(update={"gains": short_spec().gains}),
            "gains: 7 Kp/Kd pairs for ur5e's 6 joints (shoulder_pan_joint, ",
        ),
        (
            short_spec().model_copy(update={"gains": PDGains(kp=(1.0,) * 6, kd=(1.0,) * 6)}),
            "gains: 6 Kp/Kd pairs for iiwa14's 7 joints",
        ),
    ],
    ids=["robot", "per-joint", "inertials", "payload", "gains-ur5e", "gains-iiwa"],
)
def test_a_job_its_robot_cannot_run_is_refused_with_the_reason(
    spec: EpisodeSpec, reason: str
) -> None:
    result, content = execute(lease(spec), "w")
    assert result.status == JobStatus.refused
    assert reason in result.reason and "\n" not in result.reason
    assert result.scores is None and content == b""


def lease(spec: EpisodeSpec, keep_log: bool = False) -> Lease:
    job = Job(job_id="j", spec=spec, keep_log=keep_log)
    return Lease(lease_id="l", study="s", job=job, expires_in=60)


def test_the_result_carries_the_scores_and_describes_the_log() -> None:
    result, content = execute(lease(short_spec()), "w")
    assert result.status == JobStatus.ok and result.worker == "w"
    assert isinstance(result.scores, WireScores)
    assert result.scores.model_dump() == score(decode_episode(content)).model_dump()
    assert result.digest == hashlib.sha256(content).hexdigest()
    assert result.episode_bytes == len(content) > 0
    assert Result.model_validate_json(result.to_bytes()) == result  # it travels as it is


def test_a_job_that_cannot_run_has_no_scores_and_no_log() -> None:
    out_of_reach = short_spec(kind="spiral", duration=3.0, center=(3.0, 0.0, 0.4))
    result, content = execute(lease(out_of_reach), "w")
    assert result.status == JobStatus.failed and "reach" in result.reason
    assert result.scores is None and content == b""
    assert result.digest == hashlib.sha256(b"").hexdigest() and result.episode_bytes == 0


def test_scores_the_wire_cannot_carry_fail_the_job_instead_of_the_worker(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def not_finite(log: object) -> Scores:
        return score(log).model_copy(update={"f_t": float("nan")})

    monkeypatch.setattr("gainfarm.worker.job.score", not_finite)
    result, content = execute(lease(short_spec()), "w")
    assert result.status == JobStatus.failed and result.scores is None and content == b""
    assert "f_t" in result.reason and "\n" not in result.reason
