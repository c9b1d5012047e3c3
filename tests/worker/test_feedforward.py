"""A learned inverse-dynamics model as the controller's feed-forward: what it buys, and how it
reaches a worker (by content hash, over the farm, once)."""

import io
import os
import subprocess
import sys
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy.lib import format as npy_format

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.models.dynamics import (
    digest,
    feedforward_from_bytes,
    rigid_prior,
    to_bytes,
    true_model,
)
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import IDEAL_PLANT, PLAIN_PLANT, REALISTIC_PLANT
from gainfarm.worker import episode
from gainfarm.worker.episode import MissingModel, run_episode
from gainfarm.worker.feedforward import ModelCache, ModelUnavailable
from gainfarm.worker.job import simulate
from gainfarm.worker.plant import RobotGravity
from gainfarm.worker.reference import reference_for
from tests.helpers import SOFT_GAINS

RIGID_IDEAL = IDEAL_PLANT.model_copy(update={"joints": "rigid"})
TRAJECTORY = TrajectorySpec(kind="fourier", duration=2.0, seed=4)


def rigid_model_bytes() -> bytes:
    """The perfect model of the rigid ideal plant: its own rigid-body dynamics."""
    return to_bytes(rigid_prior(RIGID_IDEAL))


def test_a_perfect_model_cuts_the_tracking_error_by_a_large_factor_at_the_same_gains() -> None:
    raw = rigid_model_bytes()
    plain = EpisodeSpec(gains=SOFT_GAINS, trajectory=TRAJECTORY, plant=RIGID_IDEAL)
    learned = plain.model_copy(update={"feedforward": digest(raw)})
    without = score(run_episode(plain))
    log = run_episode(learned, rigid_prior(RIGID_IDEAL))
    with_model = score(log)
    assert not without.diverged and not with_model.diverged
    assert without.f_acc > 50 * with_model.f_acc, (without.f_acc, with_model.f_acc)
    assert log.metadata.spec.feedforward == digest(raw)  # the log says which model


def test_behind_fri_the_feedforward_leaves_gravity_to_the_robot() -> None:
    # A model predicts the whole motor torque; behind FRI the robot adds its gravity model, so
    # the worker adds the model's torque less that gravity at the reference. The arm's rigid
    # physics stands in for a learned model here (tests/analytic/data/test_learning.py learns one).
    model = rigid_prior(REALISTIC_PLANT)
    name = digest(to_bytes(model))
    errors = {}
    for plant in (REALISTIC_PLANT, PLAIN_PLANT):
        spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=TRAJECTORY, plant=plant)
        errors[plant.interface, "pd"] = score(run_episode(spec)).f_acc
        added = spec.model_copy(update={"feedforward": name})
        errors[plant.interface, "model"] = score(run_episode(added, model)).f_acc
    reference = reference_for(TRAJECTORY)
    whole = model.inverse(reference.q, reference.qd, reference.qdd)
    fri = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=TRAJECTORY, plant=REALISTIC_PLANT)
    errors["fri", "gravity twice"] = score(episode.simulate(fri, reference, whole)).f_acc
    added = episode.compensation(fri.model_copy(update={"feedforward": name}), reference, model)
    np.testing.assert_array_equal(added, whole - RobotGravity(REALISTIC_PLANT).at(reference.q))
    assert errors["fri", "model"] < 0.5 * errors["fri", "pd"], errors
    assert errors["fri", "model"] < 1.05 * errors["torque", "model"], errors
    assert errors["fri", "gravity twice"] > 3 * errors["fri", "model"], errors


def test_the_true_model_is_the_anchor_and_its_compensations_reach_below_a_millimetre() -> None:
    # A calm held-out path (a seed no other test uses) on the default plant, default gains: PD
    # alone (behind FRI, PD + gravity compensation), the nominal rigid arm's feed-forward, the
    # plant's own model through its file as a worker gets it, and that model with the spring's
    # deflection and the tick of delay compensated (bench/true_feedforward.py measures more).
    trajectory = TrajectorySpec(kind="fourier", duration=2.0, seed=4242)
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=trajectory, plant=REALISTIC_PLANT)
    errors = {"pd": score(run_episode(spec)).f_acc}
    for name, model in (("rigid", rigid_prior(REALISTIC_PLANT)), ("true", None)):
        raw = to_bytes(model or true_model(REALISTIC_PLANT))
        added = spec.model_copy(update={"feedforward": digest(raw)})
        errors[name] = score(run_episode(added, feedforward_from_bytes(raw))).f_acc
    reference = reference_for(trajectory)
    plain = episode.true_compensation(spec, reference)
    added = spec.model_copy(update={"feedforward": digest(raw)})
    np.testing.assert_array_equal(
        plain, episode.compensation(added, reference, true_model(REALISTIC_PLANT))
    )
    both = episode.true_compensation(spec, reference, delay=True, deflection=True)
    errors["compensated"] = score(episode.simulate(spec, reference, both)).f_acc
    assert errors["true"] < 0.6 * errors["rigid"] < 0.6 * errors["pd"], errors
    assert errors["true"] < 0.25 * errors["pd"], errors
    # What the true model leaves is the springs' sag and the delay: compensated, sub-millimetre.
    assert errors["compensated"] < 0.5e-3, errors
    assert errors["compensated"] < 0.3 * errors["true"], errors


def test_a_spec_naming_a_model_needs_the_model() -> None:
    spec = EpisodeSpec(
        gains=SOFT_GAINS, trajectory=TRAJECTORY, plant=RIGID_IDEAL, feedforward="ab" * 32
    )
    with pytest.raises(MissingModel):
        run_episode(spec)
    outcome = simulate(spec)  # a worker that cannot fetch: a failed job, not a crash
    assert outcome.status.value == "failed" and "ababababab" in outcome.reason


def test_feedforward_and_gravity_compensation_exclude_each_other() -> None:
    with pytest.raises(ValueError, match="exclude each other"):
        EpisodeSpec(
            gains=SOFT_GAINS,
            feedforward="ab" * 32,
            gravity_compensation=True,
            trajectory=TRAJECTORY,
        )


def test_the_cache_fetches_once_keeps_the_file_and_refuses_what_does_not_hash(
    tmp_path: Path,
) -> None:
    raw = rigid_model_bytes()
    wanted = digest(raw)
    asked: list[str] = []

    def fetch(name: str) -> bytes:
        asked.append(name)
        return raw

    cache = ModelCache(tmp_path)
    model = cache.model(wanted, fetch)
    assert model.target == "inverse" and asked == [wanted] and cache.fetched == 1
    assert (tmp_path / f"{wanted}.npz").read_bytes() == raw
    # A new process (a restarted worker) finds it on disk; a corrupted copy is fetched again.
    assert ModelCache(tmp_path).model(wanted, lambda _: None) is not None
    (tmp_path / f"{wanted}.npz").write_bytes(raw[:-10])
    again = ModelCache(tmp_path)
    again.model(wanted, fetch)
    assert again.fetched == 1 and len(asked) == 2
    with pytest.raises(ModelUnavailable, match="hash"):
        ModelCache(tmp_path / "other").model("cd" * 32, lambda _: raw)
    with pytest.raises(ModelUnavailable, match="nobody"):
        ModelCache(tmp_path / "other").model("cd" * 32, lambda _: None)
    forward = to_bytes(rigid_prior(RIGID_IDEAL, target="forward"))
    with pytest.raises(ModelUnavailable, match="inverse"):
        ModelCache(tmp_path / "other").model(digest(forward), lambda _: forward)


def test_the_cache_keeps_the_most_recently_used_models_within_its_bound(tmp_path: Path) -> None:
    files = [to_bytes(replace(rigid_prior(RIGID_IDEAL), about={"n": n})) for n in range(3)]
    names = [digest(raw) for raw in files]
    served = dict(zip(names, files, strict=True))
    cache = ModelCache(tmp_path, max_bytes=int(2.5 * len(files[0])))
    (tmp_path / "notes.txt").write_bytes(b"x" * len(files[0]))  # not the cache's: left alone
    for name in names[:2]:
        cache.model(name, served.get)
    for age, name in enumerate(names[:2]):  # the first fetched is the least recently used...
        os.utime(tmp_path / f"{name}.npz", ns=(10**18 + age, 10**18 + age))
    ModelCache(tmp_path).model(names[0], lambda _: None)  # ...until a restarted worker uses it
    cache.model(names[2], served.get)
    on_disk = sorted(path.name for path in tmp_path.iterdir())
    assert on_disk == sorted(["notes.txt", f"{names[0]}.npz", f"{names[2]}.npz"])
    small = ModelCache(tmp_path / "small", max_bytes=len(files[0]) - 1)
    assert small.model(names[1], served.get) is not None  # used, though too large to keep
    assert not (tmp_path / "small").exists() and small.fetched == 1


def test_a_served_model_lying_about_its_size_fails_the_job_not_the_worker(tmp_path: Path) -> None:
    header = io.BytesIO()
    npy_format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)}
    )
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("parameters.npy", header.getvalue())
    liar = buffer.getvalue()
    with pytest.raises(ModelUnavailable) as refused:
        ModelCache(tmp_path).model(digest(liar), lambda _: liar)
    assert str(refused.value) == (
        f"feed-forward model {digest(liar)[:12]}: 'parameters.npy': its header claims "
        "8,000,000,000,000 bytes of data, more than the member's 128"
    )
    assert list(tmp_path.iterdir()) == []  # refused bytes are not kept


@pytest.mark.slow
def test_the_model_reaches_a_worker_that_never_had_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))  # the worker processes' cache: empty
    raw = rigid_model_bytes()
    wanted = digest(raw)
    spec = EpisodeSpec(
        gains=SOFT_GAINS, trajectory=TRAJECTORY, plant=RIGID_IDEAL, feedforward=wanted
    )
    decoy = to_bytes(
        rigid_prior(IDEAL_PLANT.model_copy(update={"joints": "rigid", "inertials": "cad"}))
    )
    with local_farm(workers=1) as endpoint:
        # A study that serves other bytes under the digest: the worker refuses them, fails the
        # job with the reason, and goes on serving.
        with FarmClient([endpoint], "liar", tmp_path / "liar", models={wanted: decoy}) as farm:
            farm.submit({"j": spec})
            (failed,) = list(farm.results(timeout=60))
        assert failed.status.value == "failed" and wanted[:12] in failed.reason
        with FarmClient([endpoint], "honest", tmp_path / "run", models={wanted: raw}) as farm:
            farm.submit(
                {
                    "a": spec,
                    "b": spec.model_copy(
                        update={"trajectory": TRAJECTORY.model_copy(update={"seed": 5})}
                    ),
                }
            )
            evaluations = {result.job_id: result for result in farm.results(timeout=60)}
    assert {result.status.value for result in evaluations.values()} == {"ok"}
    assert (cache / "gainfarm" / "models" / f"{wanted}.npz").read_bytes() == raw
    log = read_episode(evaluations["a"].log)
    assert log.metadata.spec.feedforward == wanted
    # The farm's episode is the one this process simulates with the same model, bit for bit.
    assert evaluations["a"].digest == simulate(spec, lambda _: rigid_prior(RIGID_IDEAL)).digest


@pytest.mark.slow
def test_worker_episode_takes_a_model_file_and_refuses_a_bad_one_in_one_line(
    tmp_path: Path,
) -> None:
    model_dir = tmp_path / "model"
    model_dir.mkdir()
    (model_dir / "model.npz").write_bytes(rigid_model_bytes())
    (tmp_path / "forward.npz").write_bytes(to_bytes(rigid_prior(RIGID_IDEAL, target="forward")))
    (tmp_path / "junk.npz").write_bytes(b"not a model")
    worker = [sys.executable, "-m", "gainfarm.worker", "episode", "--trajectory", "fourier"]
    common = [*worker, "--duration", "1", "--plant", "ideal", "--joints", "rigid"]
    ran = subprocess.run(
        [*common, "--feedforward", str(model_dir), "--out", str(tmp_path / "e.mcap"), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert ran.returncode == 0, ran.stderr
    assert read_episode(tmp_path / "e.mcap").metadata.spec.feedforward == digest(
        rigid_model_bytes()
    )
    for bad, expected in [
        (tmp_path / "junk.npz", "--feedforward"),
        (tmp_path / "forward.npz", "inverse"),
        (tmp_path / "missing", "--feedforward"),
    ]:
        out = tmp_path / f"{bad.name}.mcap"
        ran = subprocess.run(
            [*common, "--feedforward", str(bad), "--out", str(out)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert ran.returncode != 0 and expected in ran.stderr, ran.stderr
        assert len(ran.stderr.strip().splitlines()) == 1 and "Traceback" not in ran.stderr
        assert not out.exists()


def test_in_process_evaluation_uses_the_given_model(tmp_path: Path) -> None:
    from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator

    raw = rigid_model_bytes()
    spec = EpisodeSpec(
        gains=SOFT_GAINS, trajectory=TRAJECTORY, plant=RIGID_IDEAL, feedforward=digest(raw)
    )
    with InProcessEvaluator(tmp_path, models={digest(raw): raw}) as evaluator:
        evaluator.submit({"a": spec})
        (result,) = list(evaluator.results())
    assert result.status.value == "ok"
    np.testing.assert_equal(
        read_episode(result.log).u, run_episode(spec, rigid_prior(RIGID_IDEAL)).u
    )
