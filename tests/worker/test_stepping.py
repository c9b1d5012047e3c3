"""Episodes stepped together: each log is the one its episode makes alone, byte for byte."""

import hashlib
import json
import random
from pathlib import Path

import numpy as np
import pytest

from gainfarm.models import min_substeps, resolve
from gainfarm.models.urdf import description
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.mcap_episode import episode_bytes
from gainfarm.schemas.robot import IDEAL_PLANT, PLAIN_PLANT, REALISTIC_PLANT
from gainfarm.worker.episode import compensation, simulate_all
from gainfarm.worker.job import simulate, simulate_batch
from gainfarm.worker.reference import reference_for
from tests.helpers import SOFT_GAINS, TRACKING_GAINS, short_spec

RECORDED = Path(__file__).parent / "data" / "stacked_logs.json"
LIMP = PDGains(kp=(0,) * 7, kd=(0,) * 7)  # without gravity compensation, the arm falls
PLAIN = {"interface": "torque"}
PLANTS = {
    "ideal": IDEAL_PLANT,
    "realistic": REALISTIC_PLANT,
    "realistic, plain torque": REALISTIC_PLANT.model_copy(update=PLAIN),
    "exact sensors, delay, friction": REALISTIC_PLANT.model_copy(
        update={"sensors": IDEAL_PLANT.sensors, **PLAIN}
    ),
    "no friction": REALISTIC_PLANT.model_copy(update={"friction": None}),
    "no delay": REALISTIC_PLANT.model_copy(update={"delay": 0, **PLAIN}),
    "rigid, no delay, one substep": REALISTIC_PLANT.model_copy(
        update={"delay": 0, "joints": "rigid", "substeps": 1}
    ),
    "ideal rigid": IDEAL_PLANT.model_copy(update={"joints": "rigid"}),
    "ideal behind FRI": IDEAL_PLANT.model_copy(update={"interface": "fri"}),
}


def _episodes() -> list[EpisodeSpec]:
    """Every loop and stack kind, gains that track, idle and diverge, lengths that end mid-block
    and on a block's edge (CHECK_EVERY = 250 ticks), with and without gravity compensation (the
    robot's, behind FRI, or a feed-forward on a plain torque interface)."""
    specs = []
    for index, plant in enumerate(PLANTS.values()):
        for gains in (TRACKING_GAINS, SOFT_GAINS, LIMP):
            duration = (0.5, 0.73, 1.0)[(index + len(specs)) % 3]
            spec = short_spec(duration=duration, gains=gains, seed=index)
            compensated = index % 2 == 0 and plant.interface == "torque"
            specs.append(
                spec.model_copy(update={"plant": plant, "gravity_compensation": compensated})
            )
    return specs


def _digest(log: EpisodeLog) -> str:
    return hashlib.sha256(episode_bytes(log, description())).hexdigest()


def test_every_episode_logs_the_same_bytes_alone_and_in_any_batch() -> None:
    specs = _episodes()
    prepared = []
    for spec in specs:
        reference = reference_for(spec.trajectory)
        prepared.append((spec, reference, compensation(spec, reference)))
    alone = [_digest(simulate_all([episode])[0]) for episode in prepared]
    assert len(set(alone)) == len(alone)  # every case is its own episode
    stopped = {log.metadata.diverged for log in simulate_all(prepared)}
    assert stopped == {True, False}  # the batch holds episodes that stop early, and others
    rng = random.Random(29)
    for _ in range(6):
        # With repeats: the same episode twice in one batch, side by side.
        chosen = rng.choices(range(len(specs)), k=rng.randint(2, 2 * len(specs)))
        threads = rng.choice((1, 2, 3))
        batched = simulate_all([prepared[index] for index in chosen], threads)
        assert [_digest(log) for log in batched] == [alone[index] for index in chosen], (
            chosen,
            threads,
        )


def test_plant_variants_of_one_layout_and_other_physics_steps_each_log_their_own() -> None:
    # A robust run's variants share the nominal plant's layout, but stiffer springs take more
    # physics steps a tick: a stack that stepped them all by its first's gave another episode.
    plants = []
    for factor in (1.0, 2.0, 0.5, 3.0):
        stiffer = tuple(factor * k for k in resolve(REALISTIC_PLANT).stiffness)
        plant = REALISTIC_PLANT.model_copy(update={"stiffness": stiffer})
        plants.append(plant.model_copy(update={"substeps": min_substeps(plant)}))
    assert len({plant.substeps for plant in plants}) == 3
    prepared = []
    for index, plant in enumerate(plants):
        spec = short_spec(duration=0.5, gains=TRACKING_GAINS, seed=index)
        spec = spec.model_copy(update={"plant": plant})
        reference = reference_for(spec.trajectory)
        prepared.append((spec, reference, compensation(spec, reference)))
    alone = [_digest(simulate_all([episode])[0]) for episode in prepared]
    assert [_digest(log) for log in simulate_all(prepared)] == alone


def _arrays_digest(log: EpisodeLog) -> str:
    """The log's numbers and how it ended, without the software versions its metadata names."""
    digest = hashlib.sha256()
    for name in ("t", "q", "qd", "tau", "u", "theta", "theta_d", "q_des", "qd_des", "ee", "ee_des"):
        digest.update(np.ascontiguousarray(getattr(log, name), dtype="<f8").tobytes())
    metadata = log.metadata
    ending = [metadata.ticks_run, metadata.diverged, metadata.divergence, metadata.damping]
    digest.update(json.dumps(ending).encode())
    return digest.hexdigest()


def test_a_batch_logs_what_the_tick_loop_before_mujoco_batch_logged() -> None:
    # Recorded with the per-world loop that mujoco.batch.Batch replaced (1fa6968): the engine
    # changed, the episodes did not, to the last bit.
    prepared = []
    for spec in _episodes():
        reference = reference_for(spec.trajectory)
        prepared.append((spec, reference, compensation(spec, reference)))
    recorded = json.loads(RECORDED.read_text())["digests"]
    assert [_arrays_digest(log) for log in simulate_all(prepared)] == recorded


def test_a_batch_of_jobs_gives_each_the_outcome_it_has_alone() -> None:
    good = short_spec(duration=0.5)
    too_fast = EpisodeSpec(gains=TRACKING_GAINS, trajectory=TrajectorySpec(duration=0.5))
    unknown = good.model_copy(update={"objectives": ("no-such-objective",)})
    falls = short_spec(duration=0.6, gains=LIMP).model_copy(update={"plant": PLAIN_PLANT})
    batch = [good, too_fast, unknown, falls]
    together = simulate_batch(batch, threads=2)
    for spec, outcome in zip(batch, together, strict=True):
        single = simulate(spec)
        assert (outcome.status, outcome.reason, outcome.digest, outcome.scores) == (
            single.status,
            single.reason,
            single.digest,
            single.scores,
        )
    assert [outcome.status.value for outcome in together] == ["ok", "failed", "refused", "diverged"]
    assert "too fast" in together[1].reason and "no-such-objective" in together[2].reason


@pytest.mark.parametrize("threads", [1, 2])
def test_a_batch_times_each_episode_by_its_share(threads: int) -> None:
    outcomes = simulate_batch([short_spec(duration=0.5)] * 4, threads=threads)
    assert len({outcome.timings.simulate_s for outcome in outcomes}) == 1
    assert all(
        outcome.timings.simulate_s > 0 and outcome.timings.encode_s > 0 for outcome in outcomes
    )


def test_a_job_on_a_robot_not_here_is_refused_naming_it() -> None:
    elsewhere = short_spec(duration=0.5).model_copy(
        update={"plant": REALISTIC_PLANT.model_copy(update={"robot": "xarm7"})}
    )
    (outcome,) = simulate_batch([elsewhere])
    assert outcome.status.value == "refused"
    assert "gainfarm.robots: no plug-in named 'xarm7' here" in outcome.reason
