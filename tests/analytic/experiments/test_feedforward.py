"""The feedforward experiment end to end at toy size: real MuJoCo episodes in this process, a real
linear model learnt, the true model served as a model file, and the files it writes."""

import math
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import feedforward as ff
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.schemas import TrajectorySpec
from gainfarm.schemas.robot import REALISTIC_PLANT
from tests.analytic.experiments.common import PNG, rows, stats_rows

# Three-second training paths (the pyramid needs 2.8 s), one held-out fourier path of 1.5 s.
BASE = RunConfig(pop=4, trajectories=(TrajectorySpec(duration=3.0),), generations=1, keep="front")


def in_process(study: str, directory: Path) -> InProcessEvaluator:
    return InProcessEvaluator(directory)


def refuse(study: str, directory: Path) -> InProcessEvaluator:
    raise AssertionError(f"{study} evaluated again")


@pytest.mark.slow
def test_the_experiment_compares_the_learned_feedforward_with_both_baselines(
    tmp_path: Path,
) -> None:
    found = ff.run(Experiment(tmp_path, in_process), BASE, 1, "linear", 1, 1.5, 1)
    results = {r["condition"]: r for r in rows(tmp_path / "results.csv")}
    assert set(results) == set(ff.CONDITIONS)
    error = {c: float(r["error_at_budget_mm"]) for c, r in results.items()}
    assert all(math.isfinite(v) and v > 0 for v in error.values()), error
    # The same gains with the plant's own model: far more accurate than the PD alone, and never
    # worse than with the learned model (the anchor no learned model can beat).
    assert error["pd+true"] < 0.5 * error["pd"], error
    assert error["ff+true"] < error["ff"], error
    assert results["pd"]["model_calm_nmse"] == "nan"
    assert float(results["pd+true"]["model_calm_nmse"]) < float(results["ff"]["model_calm_nmse"])
    # The true model's file is what the farm served: the one kept, of the plant's own kind.
    assert (tmp_path / "models" / "true.npz").read_bytes() == ff.to_bytes(
        ff.true_model(REALISTIC_PLANT)
    )
    # Six claims, Holm-adjusted; one repetition cannot decide, and the report says so.
    assert len(found) == 6 and {(c.a, c.b) for c in found} == {(a, b) for a, b, _ in ff.CLAIMS}
    assert all(c.p_holm >= c.result.p_value for c in found)
    assert len(stats_rows(tmp_path)) == 6
    report = (tmp_path / "report.md").read_text()
    for heading in ("**Question.**", "**Design.**", "## Findings", "## Claims", "calm episodes"):
        assert heading in report
    assert "the data cannot decide" in report
    assert (tmp_path / ff.FIGURE).read_bytes().startswith(PNG)
    # Run again: every run, model and evaluation is read back, nothing simulated again.
    again = ff.run(Experiment(tmp_path, refuse), BASE, 1, "linear", 1, 1.5, 1)
    assert [c.result for c in again] == [c.result for c in found]
