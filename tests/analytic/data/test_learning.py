"""Learning the arm's dynamics (analytic/learning.py) on small datasets of real MuJoCo episodes:
real scikit-learn training and Pinocchio identification, scored on held-out trajectories. The
plain torque plant's and the FRI plant's: the target is the motors' whole torque on both."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gainfarm.analytic.data import baselines, learning
from gainfarm.analytic.data.learning import LearnError, fit, learn, read_split, score
from gainfarm.analytic.data.loader import load_dataset
from gainfarm.models import plant_preset, robot_of
from gainfarm.models.dynamics import (
    BadDynamicsModel,
    digest,
    from_bytes,
    inconsistencies,
    load,
    physical_parameters,
    rigid_prior,
    rigid_spec,
    to_bytes,
    true_model,
)
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.objectives import score as score_episode
from gainfarm.schemas.robot import IDEAL_PLANT, JOINT_NAMES, PLAIN_PLANT, REALISTIC_PLANT
from gainfarm.worker.episode import run_episode
from tests.learning_data import SPLITS, write_dataset

REQUIRED = {"nmse", "rmse", "nmse_mean", "nmse_mean_all", "rows", "target", "kind"}
REQUIRED |= {"mean_predictor_nmse"}


@pytest.fixture(scope="module")
def realistic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six training, one validation and two test fourier episodes of 2 s, realistic plant."""
    return write_dataset(tmp_path_factory.mktemp("data") / "realistic", PLAIN_PLANT)


@pytest.fixture(scope="module")
def fri(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same episodes' trajectories on the realistic plant behind KUKA's FRI."""
    return write_dataset(tmp_path_factory.mktemp("data") / "fri", REALISTIC_PLANT)


def _leftovers(directory: Path) -> list[str]:
    return sorted(path.name for path in directory.iterdir() if path.name.startswith("."))


def test_a_split_is_its_rows_with_an_acceleration(realistic, tmp_path):
    train, test = read_split(realistic, "train"), read_split(realistic, "test")
    assert len(set(train.episode_id)) == 6 and len(set(test.episode_id)) == 2
    assert len(train) == 6 * 1001  # 1001 ticks an episode, each with its smoothed q̈
    assert train.q.shape == train.u.shape == train.qdd.shape == (6006, 7)
    assert np.isfinite(train.qdd).all() and train.calm.all()
    assert len(read_split(realistic, "nonexistent")) == 0
    # Before qdd_sg, the forward difference: the last tick of each episode has none.
    old = read_split(write_dataset(tmp_path / "old", PLAIN_PLANT, smoothed=False), "train")
    assert len(old) == 6 * 1000 and np.isfinite(old.qdd).all()


@pytest.mark.parametrize(
    ("kind", "target"),
    [("linear", "inverse"), ("mlp", "inverse"), ("residual", "inverse"), ("residual", "forward")],
)
@pytest.mark.slow
def test_learned_models_beat_the_mean_predictor_on_held_out_trajectories(
    realistic, tmp_path, kind, target
):
    out = tmp_path / "model"
    scores = learn(realistic, out, target=target, kind=kind)
    assert set(scores) >= REQUIRED
    assert set(scores["nmse"]) == set(scores["rmse"]) == set(JOINT_NAMES)
    assert (scores["kind"], scores["target"], scores["rows"]) == (kind, target, 2 * 1001)
    assert 0.8 < scores["mean_predictor_nmse"] < 1.5
    assert scores["nmse_mean"] < 0.5, scores["nmse"]
    assert scores["nmse_mean"] == pytest.approx(
        np.mean([scores["nmse"][j] for j in JOINT_NAMES[:6]])
    )

    assert json.loads((out / "scores.json").read_text()) == scores
    raw = (out / "model.npz").read_bytes()
    assert digest(raw) == scores["digest"]
    model = from_bytes(raw)
    assert (model.kind, model.target) == (kind, target)
    assert model.about["train_rows"] == 6 * 1001
    report = (out / "report.md").read_text()
    assert "prediction.png" in report and scores["digest"] in report and "| A6 |" in report
    assert (out / "prediction.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in out.iterdir()) == [
        "model.npz",
        "prediction.png",
        "report.md",
        "scores.json",
    ]
    assert _leftovers(tmp_path) == []


def test_learning_adds_what_the_rigid_prior_leaves_out(realistic, tmp_path):
    # The realistic plant's friction and elastic joints are not in the rigid physics: the
    # residual network and the identified friction must explain much of what it misses.
    prior = score(fit(realistic, "inverse", "rigid"), realistic)
    residual = score(fit(realistic, "inverse", "residual"), realistic)
    linear = score(fit(realistic, "inverse", "linear"), realistic)
    assert residual["nmse_mean"] < 0.8 * prior["nmse_mean"]
    assert linear["nmse_mean"] < 0.3 * prior["nmse_mean"]


def test_behind_fri_the_target_is_the_motors_whole_torque(realistic, fri):
    # The robot adds its gravity model to u behind FRI: the rigid prior explains u_motor as
    # well as it explains the plain plant's u, and u alone not at all on the gravity joints.
    plain_prior = score(fit(realistic, "inverse", "rigid"), realistic)
    fri_prior = score(fit(fri, "inverse", "rigid"), fri)
    assert fri_prior["nmse_mean"] < 1.1 * plain_prior["nmse_mean"] < 0.5, (fri_prior, plain_prior)
    ticks = pq.read_table(fri / "ticks.parquet", filters=[("split", "==", "test")]).to_pydict()
    usable = np.isfinite(ticks["qdd_A1"])

    def joints(signal: str) -> np.ndarray:
        return np.column_stack([ticks[f"{signal}_{joint}"] for joint in JOINT_NAMES])[usable]

    q, qd, qdd, u = (joints(signal) for signal in ("q", "qd", "qdd", "u"))
    predicted = fit(fri, "inverse", "rigid").inverse(q, qd, qdd)
    missed = ((predicted - u) ** 2).mean(axis=0) / u.var(axis=0)  # the prior's nMSE on u
    assert missed[1] > 10 * fri_prior["nmse"]["A2"], missed  # A2 carries most of the gravity
    linear = score(fit(fri, "inverse", "linear"), fri)
    assert linear["nmse_mean"] < 0.3 * fri_prior["nmse_mean"]


def test_a_model_learned_behind_fri_is_the_feedforward_there(realistic, fri):
    # Learned from FRI logs or plain ones, a model means the arm's dynamics: either, added as
    # the feed-forward on a held-out trajectory, tracks as well behind FRI as on the plain
    # plant, and far better than the PD alone.
    learned = {
        "fri": fit(fri, "inverse", "linear"),
        "plain": fit(realistic, "inverse", "linear"),
    }
    held_out = TrajectorySpec(kind="fourier", seed=9, duration=2.0)
    errors = {}
    for plant in (REALISTIC_PLANT, PLAIN_PLANT):
        spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=held_out, plant=plant)
        errors[plant.interface, "pd"] = score_episode(run_episode(spec)).f_acc
        for source, model in learned.items():
            added = spec.model_copy(update={"feedforward": digest(to_bytes(model))})
            errors[plant.interface, source] = score_episode(run_episode(added, model)).f_acc
    assert errors["fri", "fri"] < 0.2 * errors["fri", "pd"], errors
    assert errors["fri", "fri"] < 1.05 * errors["torque", "plain"], errors
    assert errors["fri", "plain"] == pytest.approx(errors["fri", "fri"], rel=0.05), errors
    assert errors["torque", "fri"] == pytest.approx(errors["torque", "plain"], rel=0.05), errors


def test_a_dataset_from_before_u_motor_learns_its_u_unless_it_was_behind_fri(realistic, tmp_path):
    # Datasets from before u_motor were of plain torque plants: their u is the motor torque.
    old = write_dataset(tmp_path / "old", PLAIN_PLANT, motor_column=False)
    for split in ("train", "test"):
        np.testing.assert_array_equal(read_split(old, split).u, read_split(realistic, split).u)
    scores = learn(old, tmp_path / "m", kind="rigid")
    assert scores["nmse_mean"] == pytest.approx(
        score(rigid_prior(PLAIN_PLANT), realistic)["nmse_mean"]
    )
    assert "`u`, the motors' whole torque" in (tmp_path / "m" / "report.md").read_text()
    fri = write_dataset(tmp_path / "fri", REALISTIC_PLANT, [(7, "test")], motor_column=False)
    _refused(fri, tmp_path / "n", "no u_motor column and holds episodes behind FRI", kind="rigid")


@pytest.mark.slow
def test_a_network_is_the_same_for_the_same_seed(realistic):
    first = to_bytes(fit(realistic, "inverse", "mlp", seed=1))
    assert to_bytes(fit(realistic, "inverse", "mlp", seed=1)) == first
    assert to_bytes(fit(realistic, "inverse", "mlp", seed=2)) != first


@pytest.mark.slow
def test_the_rigid_prior_scores_near_zero_on_a_rigid_plant(tmp_path):
    # One physics step a tick and exact sensors: the forward difference of q̇ (a dataset
    # without qdd_sg, so it is what learn reads) is the very acceleration MuJoCo integrated.
    plant = IDEAL_PLANT.model_copy(update={"joints": "rigid", "substeps": 1})
    splits = [(0, "train"), (1, "test")]
    dataset = write_dataset(tmp_path / "rigid", plant, splits, 1.0, smoothed=False)
    for target in ("inverse", "forward"):
        scores = learn(dataset, tmp_path / target, target=target, kind="rigid")
        assert scores["nmse_mean_all"] < 1e-20, scores["nmse"]


def test_a_dataset_of_mixed_plants_uses_the_first_and_says_so(tmp_path):
    rigid = IDEAL_PLANT.model_copy(update={"joints": "rigid"})
    dataset = write_dataset(tmp_path / "one", rigid, [(0, "test")], 0.5)
    other = write_dataset(tmp_path / "two", IDEAL_PLANT, [(1, "test")], 0.5)
    for name in ("ticks.parquet", "episodes.parquet"):
        both = pa.concat_tables([pq.read_table(dataset / name), pq.read_table(other / name)])
        pq.write_table(both, dataset / name)
    learn(dataset, tmp_path / "model", kind="rigid")
    assert "mix 2 plants (the same rigid arm)" in (tmp_path / "model" / "report.md").read_text()
    assert load(tmp_path / "model" / "model.npz").spec.inertials == "open"


# --- refusals ---------------------------------------------------------------------------------


def _refused(dataset: Path, out: Path, message: str, **options: str) -> None:
    with pytest.raises(LearnError, match=message) as caught:
        learn(dataset, out, **options)
    assert "\n" not in str(caught.value)
    assert not out.exists()
    assert _leftovers(out.parent) == []


def test_a_linear_forward_model_is_refused(realistic, tmp_path):
    _refused(
        realistic, tmp_path / "m", "linear model is inverse only", target="forward", kind="linear"
    )


def test_a_dataset_without_a_test_split_is_refused(tmp_path):
    dataset = write_dataset(tmp_path / "d", PLAIN_PLANT, SPLITS[:2], 2.0)
    _refused(dataset, tmp_path / "m", "the dataset has no test split: build it with --split")


def test_a_dataset_without_training_rows_is_refused(tmp_path):
    dataset = write_dataset(tmp_path / "d", PLAIN_PLANT, [(7, "test")], 2.0)
    _refused(dataset, tmp_path / "m", "no rows in its train split", kind="mlp")


def test_a_missing_or_unreadable_dataset_is_refused(tmp_path):
    _refused(tmp_path / "absent", tmp_path / "m", "holds no dataset")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "episodes.parquet").write_bytes(b"not parquet")
    _refused(tmp_path / "junk", tmp_path / "m", "unreadable episodes.parquet")


def test_an_existing_out_directory_is_refused_and_left_alone(realistic, tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "keep").write_text("mine")
    with pytest.raises(LearnError, match="already exists"):
        learn(realistic, tmp_path / "m", kind="rigid")
    assert [p.name for p in (tmp_path / "m").iterdir()] == ["keep"]


def test_an_out_that_cannot_be_a_directory_is_refused_naming_the_option_before_any_fit(
    tmp_path: Path,
) -> None:
    """Before the dataset is read, let alone fitted: no dataset is needed to be refused."""
    (tmp_path / "notes").write_text("mine")
    for out, says in (
        ("notes", "--out: 'notes' already exists"),
        ("notes/model", "--out: cannot write 'notes/model': 'notes' is a file"),
        ("notes/a/model", "--out: cannot write 'notes/a/model': 'notes' is a file"),
    ):
        ran = subprocess.run(
            [sys.executable, "-m", "gainfarm.analytic", "learn", "no-dataset", "--out", out],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=tmp_path,
        )
        assert ran.returncode == 2, ran.stderr
        assert ran.stderr == f"analytic: error: {says}\n"
    assert [path.name for path in tmp_path.iterdir()] == ["notes"]


def test_a_failure_while_writing_leaves_nothing(realistic, tmp_path, monkeypatch):
    def full_disk(*args: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(learning, "plot_prediction", full_disk)
    _refused(realistic, tmp_path / "m", "cannot write .*No space left on device", kind="rigid")


@pytest.mark.slow
def test_the_learn_command_writes_a_model_the_feedforward_takes_and_refuses_in_one_line(
    realistic, tmp_path
):
    learn_command = [sys.executable, "-m", "gainfarm.analytic", "learn"]
    ran = subprocess.run(
        [*learn_command, str(realistic), "--out", str(tmp_path / "m"), "--kind", "linear"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ran.returncode == 0, ran.stderr
    assert "linear inverse model, test nMSE" in ran.stdout
    scores = json.loads((tmp_path / "m" / "scores.json").read_text())
    assert scores["nmse_mean"] < 0.5 and set(scores["nmse"]) == set(JOINT_NAMES)
    worker = [sys.executable, "-m", "gainfarm.worker", "episode", "--trajectory", "fourier"]
    ran = subprocess.run(
        [*worker, "--duration", "1", "--feedforward", str(tmp_path / "m")],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert ran.returncode == 0, ran.stderr
    no_test = write_dataset(tmp_path / "d", PLAIN_PLANT, SPLITS[:2], 1.0)
    for arguments, expected in [
        ([str(no_test), "--out", str(tmp_path / "n")], "no test split"),
        ([str(realistic), "--out", str(tmp_path / "n"), "--kind", "nope"], "--kind"),
        ([str(realistic), "--out", str(tmp_path / "n"), "--target", "x"], "--target"),
    ]:
        ran = subprocess.run(
            [*learn_command, *arguments], capture_output=True, text=True, timeout=300
        )
        assert ran.returncode != 0 and expected in ran.stderr, ran.stderr
        assert "Traceback" not in ran.stderr
        assert not (tmp_path / "n").exists()


# --- honest scores: the smoothed acceleration, calm episodes, the floor ------------------------


def test_the_smoothed_acceleration_gives_the_plants_own_model_its_floor(fri, tmp_path):
    """The forward difference of the measured q̇ is noise a model cannot predict: even the
    plant's own dynamics score far worse on it than on qdd_sg, which is what read_split gives."""
    old = write_dataset(tmp_path / "old", REALISTIC_PLANT, smoothed=False)
    assert learning.acceleration_column(old) == "qdd"
    assert learning.acceleration_column(fri) == "qdd_sg"
    differenced = score(true_model(REALISTIC_PLANT), old)["nmse_mean"]
    smoothed = score(true_model(REALISTIC_PLANT), fri)["nmse_mean"]
    assert smoothed < 0.01 and smoothed < differenced / 10, (smoothed, differenced)


def test_calm_scores_leave_the_rough_episodes_out(tmp_path):
    both = write_dataset(
        tmp_path / "both", PLAIN_PLANT, [(0, "train"), (7, "test"), (8, "test")], rough=(8,)
    )
    calm = write_dataset(tmp_path / "calm", PLAIN_PLANT, [(0, "train"), (7, "test")])
    prior = rigid_prior(PLAIN_PLANT)
    mixed, alone = score(prior, both), score(prior, calm)
    assert mixed["rows"] == 2 * alone["rows"] and mixed["calm"]["rows"] == alone["rows"]
    for key in ("nmse_mean", "rmse_a1_a4"):
        assert mixed["calm"][key] == pytest.approx(alone[key])
        assert mixed[key] != pytest.approx(alone[key])
    assert alone["calm"]["nmse_mean"] == alone["nmse_mean"]  # every episode calm


def test_learn_puts_the_model_beside_the_floor_and_the_prior(fri, tmp_path):
    scores = learn(fri, tmp_path / "m", kind="linear")
    assert inconsistencies(load(tmp_path / "m" / "model.npz").parameters) == []
    floor = score(true_model(REALISTIC_PLANT), fri)
    prior = score(rigid_prior(REALISTIC_PLANT), fri)
    assert scores["floor"]["nmse_mean"] == pytest.approx(floor["nmse_mean"])
    assert scores["prior"]["nmse_mean"] == pytest.approx(prior["nmse_mean"])
    # Identification on the smoothed acceleration comes near the floor, far below the prior.
    assert scores["nmse_mean"] < 5 * floor["nmse_mean"] < prior["nmse_mean"], scores["nmse"]
    report = (tmp_path / "m" / "report.md").read_text()
    assert f"| plant's own dynamics (the floor) | {floor['nmse_mean']:.4f} |" in report
    assert f"| rigid prior (untrained) | {prior['nmse_mean']:.4f} |" in report
    assert "`qdd_sg`" in report and "0.14 N·m" in report


# --- the benchmark's baselines -----------------------------------------------------------------


def test_the_history_inputs_are_earlier_ticks_of_the_same_episode():
    n = 6
    rows = learning.Rows(
        episode_id=np.array(["a"] * 3 + ["b"] * 3),
        t=np.array([0, 1, 2, 0, 1, 2]) * 0.002,
        q=np.zeros((n, 7)),
        qd=np.arange(n, dtype=float)[:, None] * np.ones(7),
        qdd=10 * np.arange(n, dtype=float)[:, None] * np.ones(7),
        u=np.zeros((n, 7)),
        calm=np.ones(n, bool),
    )
    x = baselines.history_inputs(rows)
    assert x.shape == (n, 21 + 14 * len(baselines.HISTORY_LAGS))
    lag_one_qd = x[:, 21]  # q̇ one tick before, A1; an episode's first tick repeats itself
    np.testing.assert_array_equal(lag_one_qd, [0, 0, 1, 3, 3, 4])
    lag_one_qdd = x[:, 28]
    np.testing.assert_array_equal(lag_one_qdd, [0, 0, 10, 30, 30, 40])


@pytest.mark.slow
def test_the_benchmark_scores_every_baseline_beside_the_floor(fri):
    table = baselines.benchmark(fri, kinds=("plant", "rigid", "gp", "history"))
    assert list(table) == ["plant", "rigid", "gp", "history"]
    floor, prior = table["plant"]["nmse_mean"], table["rigid"]["nmse_mean"]
    for kind in ("gp", "history"):  # each learns some of what the prior leaves out
        assert floor < table[kind]["nmse_mean"] < 0.9 * prior, (kind, table[kind]["nmse"])
        assert table[kind]["calm"]["rows"] == table[kind]["rows"] and table[kind]["fit_seconds"] > 0
    assert set(table["gp"]) >= REQUIRED | {"calm", "rmse_a1_a4"}


def test_identified_parameters_that_are_no_arm_are_named():
    documented = physical_parameters(rigid_spec(REALISTIC_PLANT))
    assert inconsistencies(documented) == []
    broken = documented.copy()
    broken[10] = -1.0  # A2's mass
    broken[20 + 4] = 50.0  # A3's Ixx·… far above the others: no body has such moments
    broken[-1] = -0.5  # A7's Coulomb friction
    found = inconsistencies(broken, JOINT_NAMES)
    assert found[0].startswith("link A2: mass -1")
    assert any(text.startswith("link A3:") for text in found)
    assert found[-1] == "A7: Coulomb friction -0.5"
    # Unnamed, the joints are counted: an arm of any joints.
    assert inconsistencies(broken)[0].startswith("link J2: mass -1")


HEAVY = REALISTIC_PLANT.model_copy(update={"payload": 3.0, "mass_scale": (1.1,) * 7})


def merged(path: Path, nominal: Path, variant: Path) -> Path:
    """One dataset of both: the variant's episodes under their own ids (v-...)."""
    path.mkdir()
    for name in ("ticks.parquet", "episodes.parquet"):
        parts = [pq.read_table(d / name) for d in (nominal, variant)]
        ids = pa.array([f"v-{e}" for e in parts[1]["episode_id"].to_pylist()])
        column = parts[1].schema.get_field_index("episode_id")
        parts[1] = parts[1].set_column(column, "episode_id", ids)
        pq.write_table(pa.concat_tables(parts), path / name)
    return path


def test_a_model_learns_one_plant_and_is_scored_on_the_variants_apart(fri, tmp_path):
    """Dataset version 5: the variants' episodes in *_variants are not learned from; the
    benchmark scores them apart, where the floor is each episode's own plant."""
    nominal = write_dataset(tmp_path / "nominal", REALISTIC_PLANT, [(0, "train"), (7, "test")])
    variant = write_dataset(
        tmp_path / "variant", HEAVY, [(0, "train_variants"), (7, "test_variants")]
    )
    both = merged(tmp_path / "both", nominal, variant)
    assert learning.plants(both) == [REALISTIC_PLANT]
    assert learning.plants(both, variants=True) == [HEAVY]
    assert set(learning.read_split(both, "train").episode_id) == {"fourier-0"}
    table = baselines.benchmark(both, kinds=("plant", "rigid"))
    alone = baselines.benchmark(nominal, kinds=("plant", "rigid"))
    for kind in ("plant", "rigid"):  # the test split as if the variants were not there
        assert table[kind]["nmse_mean"] == alone[kind]["nmse_mean"]
        assert table[kind]["variants"]["rows"] == table[kind]["rows"]
    # Its own plant predicts each variant episode; the nominal plant's rigid arm does not.
    assert table["plant"]["variants"]["nmse_mean"] < 0.1 * table["rigid"]["variants"]["nmse_mean"]
    learning.learn(both, tmp_path / "model", kind="rigid")
    report = (tmp_path / "model" / "report.md").read_text()
    assert "not learned from: the *_variants splits' episodes, on 1 other plants" in report
    assert "the episodes mix" not in report  # one plant learned from


def test_the_floor_of_a_dataset_of_plants_is_each_episodes_own(fri, tmp_path):
    """A dataset of plant variants (analytic dataset --plants): the floor predicts each
    episode with its own plant, as well as each plant's floor alone; the first plant's model
    on every episode does far worse."""
    splits = [(0, "train"), (7, "test")]
    nominal = write_dataset(tmp_path / "nominal", REALISTIC_PLANT, splits)
    variant = write_dataset(tmp_path / "variant", HEAVY, splits)
    mixed = merged(tmp_path / "mixed", nominal, variant)
    floor = baselines.benchmark(mixed, kinds=("plant",))["plant"]
    alone = [
        score(true_model(plant), d)["nmse_mean"]
        for plant, d in ((REALISTIC_PLANT, nominal), (HEAVY, variant))
    ]
    first = score(true_model(REALISTIC_PLANT), mixed)["nmse_mean"]
    assert floor["nmse_mean"] < 2 * max(alone) and first > 5 * floor["nmse_mean"], (
        floor,
        alone,
        first,
    )


# --- another arm: the UR5e (6 joints) ------------------------------------------------------------


@pytest.fixture(scope="module")
def ur5e(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same splits' fourier episodes on the realistic UR5e: columns named by its joints, its
    metadata naming it, as the builder writes them."""
    plant = plant_preset("realistic", "ur5e")
    return write_dataset(tmp_path_factory.mktemp("data") / "ur5e", plant)


def test_a_ur5e_dataset_reads_as_six_joints(ur5e, realistic):
    joints = robot_of("ur5e").joint_names
    train = read_split(ur5e, "train")
    assert train.joints == joints and train.q.shape == train.u.shape == (6 * 1001, 6)
    split = load_dataset(ur5e, "train")
    assert (split.robot, split.joint_names) == ("ur5e", joints)
    assert split.inputs().shape == (6 * 1001, 18) and split.targets().shape == (6 * 1001, 6)
    # A dataset that names no arm is the iiwa 14's, as every one before other arms was.
    assert load_dataset(realistic, "test").joint_names == JOINT_NAMES


def test_the_true_model_is_the_floor_of_ur5e_data_and_a_network_takes_18_inputs(ur5e, tmp_path):
    floor = score(fit(ur5e, "inverse", "plant"), ur5e)
    prior = score(fit(ur5e, "inverse", "rigid"), ur5e)
    assert set(floor["nmse"]) == set(robot_of("ur5e").joint_names)
    assert floor["nmse_mean"] < 0.05 and floor["nmse_mean"] < prior["nmse_mean"], (floor, prior)
    out = tmp_path / "model"
    scores = learn(ur5e, out, kind="mlp")
    model = from_bytes((out / "model.npz").read_bytes())
    assert model.robot == "ur5e" and model.network is not None
    assert model.network.weights[0].shape[0] == 18 and model.network.weights[-1].shape[1] == 6
    # Its mean leaves out the flange's joint, as the iiwa's leaves out A7.
    mean = np.mean([scores["nmse"][j] for j in robot_of("ur5e").joint_names[:5]])
    assert scores["nmse_mean"] == pytest.approx(mean)
    assert scores["nmse_mean"] < 0.5 and scores["floor"]["nmse_mean"] < scores["nmse_mean"]
    report = (out / "report.md").read_text()
    assert "| wrist_3_joint |" in report and "shoulder_pan_joint-wrist_2_joint" in report
    assert "real iiwa 14" not in report  # the published figure is the iiwa's alone
    # A model of the UR5e is refused where it would drive the iiwa 14.
    with pytest.raises(BadDynamicsModel, match=r"model of ur5e .* cannot drive iiwa14"):
        load(out / "model.npz", robot="iiwa14")


def test_a_ur5e_linear_model_identifies_78_parameters(ur5e):
    model = fit(ur5e, "inverse", "linear")
    assert model.parameters is not None and model.parameters.shape == (78,)
    assert model.about["inconsistencies"] == []  # consistent by construction
    assert score(model, ur5e)["nmse_mean"] < 0.2


def test_a_model_of_another_arm_is_not_scored_on_a_dataset(ur5e, realistic):
    iiwa = fit(realistic, "inverse", "rigid")
    with pytest.raises(LearnError, match=r"model of iiwa14 \(7 joints\) cannot drive ur5e"):
        score(iiwa, ur5e)
    # As many joints is not the same arm: the Panda's prior on the iiwa's data.
    panda = rigid_prior(plant_preset("realistic", "panda"))
    with pytest.raises(LearnError, match=r"model of panda .* cannot drive iiwa14"):
        score(panda, realistic)
