"""The dataset-value experiment: real MuJoCo episodes (in-process), real training, real tests."""

import contextlib
import csv
import math
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import dataset_value as dv
from gainfarm.analytic.experiments import dataset_value_measures as dvm
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.experiments.statistics import holm
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.worker.episode import motor_torque, run_episode
from tests.analytic.experiments.common import refusal
from tests.helpers import TRACKING_GAINS, write_log

BASE = RunConfig(pop=4, trajectories=(TrajectorySpec(duration=3.0),), generations=1, keep="front")
REPS, TESTS, TICKS = 3, 2, 300
PNG = b"\x89PNG\r\n\x1a\n"
# A few hundred rows are fewer than the networks' mini-batch: scikit-learn says so each epoch.
pytestmark = pytest.mark.filterwarnings("ignore:Got `batch_size`:UserWarning")


# Evaluators open now and the most open at once, for tuning runs and for batches of episodes.
OPEN = {"runs": [0, 0], "batches": [0, 0]}
LOCK = threading.Lock()


@contextlib.contextmanager
def in_process(study: str, directory: Path) -> Iterator[InProcessEvaluator]:
    kind = "batches" if directory.parent.name == dv.SIMULATED else "runs"
    with LOCK:
        OPEN[kind][0] += 1
        OPEN[kind][1] = max(OPEN[kind])
    try:
        with InProcessEvaluator(directory) as evaluator:
            yield evaluator
    finally:
        with LOCK:
            OPEN[kind][0] -= 1


def refuse(study: str, directory: Path) -> InProcessEvaluator:
    raise AssertionError(f"{study} simulated again")


def rows(path: Path) -> list[dict[str, str]]:
    with path.open() as stream:
        return list(csv.DictReader(stream))


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, dvm.Conclusion]]:
    out = tmp_path_factory.mktemp("dataset-value")
    found = dv.run(Experiment(out, in_process), BASE, REPS, TESTS, TICKS)
    yield out, found


@pytest.mark.slow
def test_every_condition_model_and_rep_is_scored_at_equal_ticks(
    finished: tuple[Path, dvm.Conclusion],
) -> None:
    out, _ = finished
    results = rows(out / "results.csv")
    baselines = {r["model"]: r for r in results if r["model"] in dvm.BASELINES}
    trained = [r for r in results if r["model"] not in dvm.BASELINES]
    assert sorted(baselines) == sorted(dvm.BASELINES)
    assert all(r["train_rows"] == "0" and r["rep"] == "all" for r in baselines.values())
    # The true model is the floor: on the same rows it beats the untrained nominal arm and every
    # model trained on a few hundred of them (noisy q̈ could let a large fit shrink below it;
    # 300 rows cannot).
    floor = float(baselines[dvm.FLOOR_MODEL]["nmse_mean"])
    assert floor < float(baselines[dvm.REFERENCE_MODEL]["nmse_mean"])
    assert floor < min(float(r["nmse_mean"]) for r in trained)
    assert sorted((int(r["rep"]), r["condition"], r["model"]) for r in trained) == sorted(
        (rep, condition, model)
        for rep in range(REPS)
        for condition in dvm.CONDITIONS
        for model in dvm.MODELS
    )
    # Equal ticks: every condition learned from the same number of rows, however large its pool.
    assert {r["train_rows"] for r in trained} == {str(TICKS)}
    assert all(int(r["pool_ticks"]) >= TICKS for r in trained)
    pools = {r["condition"]: int(r["pool_ticks"]) for r in trained if r["rep"] == "0"}
    assert pools["specific-rerun"] == 3 * pools["specific-knee"]  # the knees on all three
    assert pools["default"] == 3 * 1501  # three whole 3 s episodes, every tick (qdd_sg)
    # One test pool for all: the same rows (by digest) in every row of the table.
    assert len({(r["test_digest"], r["test_rows"]) for r in results}) == 1
    assert int(results[0]["test_rows"]) == 3 * TESTS * 1501
    for r in results:
        nmse = [float(r[f"nmse_A{j}"]) for j in range(1, 8)]
        assert all(math.isfinite(v) and v > 0 for v in nmse)
        assert float(r["nmse_mean"]) == pytest.approx(np.mean(nmse[:6]))
        rmse = [float(r[f"rmse_A{j}"]) for j in range(1, 8)]
        assert float(r["rmse_mean"]) == pytest.approx(np.mean(rmse[:6]))


@pytest.mark.slow
def test_every_run_of_every_repetition_ran_at_once(finished: tuple[Path, dvm.Conclusion]) -> None:
    """As wide as the farm: the twelve tuning runs (three specific and one generic per
    repetition) were all open together, and then the batches they call for: the default gains
    once, each specific knee on the other two trajectories, each repetition's random
    controllers (and before all of them, alone, the test pool)."""
    assert OPEN["runs"][1] == 4 * REPS
    assert OPEN["batches"][1] == 1 + 3 * REPS + REPS


@pytest.mark.slow
def test_comparisons_report_and_figure(finished: tuple[Path, dvm.Conclusion]) -> None:
    out, found = finished
    comparisons = rows(out / "comparisons.csv")
    # Ten per model (five tuned selections × default and random), then best against runner-up.
    assert len(comparisons) == 10 * len(dvm.MODELS) + 1
    for c in comparisons:
        assert 0 <= float(c["p"]) <= 1 and 0 <= float(c["p_holm"]) <= 1
        assert float(c["p_holm"]) >= float(c["p"])
        assert math.isfinite(float(c["d_z"])) and c["n"] == str(REPS)
    # Holm over every model's claims as one family; the last row is a test of its own.
    family = comparisons[:-1]
    assert [float(c["p_holm"]) for c in family] == pytest.approx(
        holm([float(c["p"]) for c in family])
    )
    assert comparisons[-1]["p_holm"] == comparisons[-1]["p"]
    report = (out / "report.md").read_text()
    assert found.text in report and "## Limitations" in report
    assert report.index("## Question") < report.index("## Design") < report.index("## Findings")
    assert "## Test RMSE (N·m)" in report and "| (true model (floor), untrained) |" in report
    assert "the floor" in found.text and "N·m" in found.text
    assert "the paper's claim" in found.text and "The most useful selection is" in found.text
    assert found.model in dvm.MODELS and found.best_selection in dvm.TUNED
    assert f"| {found.best_selection} |" in report
    assert (out / dv.FIGURE).read_bytes().startswith(PNG)
    assert f"![{dv.FIGURE}]({dv.FIGURE})" in report


@pytest.mark.slow
def test_a_second_invocation_reuses_the_runs_and_episodes(
    finished: tuple[Path, dvm.Conclusion],
) -> None:
    out, _ = finished
    runs = sorted(path.name for path in (out / "runs").iterdir())
    assert len(runs) == 4 * REPS  # three specific and one generic per repetition
    checkpoints = {p: p.stat().st_mtime_ns for p in out.glob("runs/*/checkpoint.pkl")}
    again = Experiment(out, refuse)  # any simulation at all fails the test
    pools = dv.all_pools(again, BASE, REPS)[1]
    test, _ = dv.test_pool(again, 3.0, TESTS, BASE.plant)
    assert {p: p.stat().st_mtime_ns for p in out.glob("runs/*/checkpoint.pkl")} == checkpoints
    assert all(path.is_file() for pool in pools.values() for path in pool.values())
    assert dvm.rows_digest(test) == rows(out / "results.csv")[0]["test_digest"]


@pytest.mark.slow
def test_subsampling_is_seeded_and_splits_a_fifth_for_validation(
    finished: tuple[Path, dvm.Conclusion],
) -> None:
    out, _ = finished
    pool = dvm.pool_rows(dv.all_pools(Experiment(out, refuse), BASE, REPS)[0]["default"])
    train, validation = dvm.subsample(pool, 1000, seed=3)
    again, _ = dvm.subsample(pool, 1000, seed=3)
    other, _ = dvm.subsample(pool, 1000, seed=4)
    assert (len(train), len(validation)) == (800, 200)
    assert np.array_equal(train.u, again.u) and not np.array_equal(train.u, other.u)
    keys = {(e, t) for e, t in zip(train.episode_id, train.t, strict=True)}
    assert not keys & {(e, t) for e, t in zip(validation.episode_id, validation.t, strict=True)}
    with pytest.raises(ValueError, match="--ticks"):
        dvm.subsample(pool, len(pool) + 1, seed=0)


def test_the_rows_hold_the_motors_whole_torque(tmp_path: Path) -> None:
    # Behind FRI (the default plant) the models learn u_motor, the command and the robot's
    # gravity model, as analytic learn does, every tick with its smoothed q̈.
    spec = EpisodeSpec(
        gains=TRACKING_GAINS, trajectory=TrajectorySpec(kind="fourier", duration=0.5)
    )
    log = run_episode(spec)
    write_log(log, tmp_path / "e.mcap")
    rows = dvm.episode_rows(tmp_path / "e.mcap", "e")
    np.testing.assert_array_equal(rows.u, motor_torque(log))
    assert not np.array_equal(rows.u, log.u)


# --- the statistics on numbers whose answer is known --------------------------------------------


def synthetic(tuned: float, default: float, reps: int, noise: float = 0.01) -> dict:
    """nmse_mean per (model, condition): tuned selections near `tuned`, default near `default`,
    random at 0.5; independent seeded noise per repetition."""
    rng = np.random.default_rng(0)
    nmse = {}
    for model in dvm.MODELS:
        for number, condition in enumerate(dvm.CONDITIONS):
            centre = {"default": default, "random": 0.5}.get(condition, tuned + 0.01 * number)
            nmse[(model, condition)] = list(centre + noise * rng.standard_normal(reps))
    return nmse


def test_a_clear_difference_is_significant_with_the_right_sign() -> None:
    nmse = synthetic(tuned=0.10, default=0.30, reps=6)
    comparisons = dvm.compare(nmse)
    against_default = [c for c in comparisons if c.against == "default"]
    assert all(c.p_holm < 0.05 and c.mean_difference < 0 and c.d_z < 0 for c in against_default)
    found = dvm.findings(nmse, comparisons)
    assert set(found.against_default.values()) == {"better"}
    assert "claim of a richer database holds here" in found.text
    assert found.best_selection == "specific-front"  # the lowest centre
    # The other way round: the tuned data worse, and said so.
    worse = dvm.findings(nmse2 := synthetic(tuned=0.4, default=0.1, reps=6), dvm.compare(nmse2))
    assert set(worse.against_default.values()) == {"worse"}
    assert "contradicted" in worse.text


def test_identical_numbers_cannot_decide() -> None:
    nmse = synthetic(tuned=0.2, default=0.2, reps=5, noise=0.0)
    for condition in dvm.TUNED:  # exactly the default's numbers
        for model in dvm.MODELS:
            nmse[(model, condition)] = list(nmse[(model, "default")])
    comparisons = dvm.compare(nmse)
    assert all(c.p == 1.0 and c.d_z == 0.0 for c in comparisons if c.against == "default")
    found = dvm.findings(nmse, comparisons)
    assert set(found.against_default.values()) == {"cannot decide"}
    assert "cannot decide" in found.text


def test_fewer_than_three_repetitions_cannot_decide() -> None:
    nmse = synthetic(tuned=0.1, default=0.9, reps=2)
    comparisons = dvm.compare(nmse)
    assert all(math.isnan(c.p) and c.finding == "cannot decide" for c in comparisons)
    found = dvm.findings(nmse, comparisons)
    assert "cannot decide" in found.text and "2 repetitions" in found.text


def test_holm_adjusts_step_down() -> None:
    assert holm([0.01, 0.04, 0.03, math.nan]) == pytest.approx(
        [0.03, 0.06, 0.06, math.nan], nan_ok=True
    )


def test_chattering_test_controllers_are_passed_over() -> None:
    default = [0.2, 0.1]
    candidates = [[5000.0, 0.1], [0.3, 0.2], [30.0, 0.1], [0.2, 0.05]]
    assert dvm.smooth_controllers(default, candidates, 2) == [1, 3]
    with pytest.raises(ValueError, match="chattering"):
        dvm.smooth_controllers(default, candidates, 3)


# --- the command line ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("arguments", "option"),
    [
        (["--ticks", "0"], "--ticks: "),
        (["--test-trajectories", "0"], "--test-trajectories: "),
        (["--ticks", "100000"], "--ticks: "),
        (["--duration", "2"], "--duration: "),
    ],
)
@pytest.mark.slow
def test_bad_input_is_one_line_naming_the_option_and_writes_nothing(
    tmp_path: Path, arguments: list[str], option: str
) -> None:
    assert refusal(tmp_path, "dataset-value", *arguments).startswith(option)
