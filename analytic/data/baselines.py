"""The baselines a dynamics researcher expects beside the rigid prior, identification and the
networks: a Gaussian process, and a model with history. For the benchmark table
(`benchmark` here, a release's card) only: each predicts from a split's rows (the history
model needs each tick's predecessors in its episode), not from one (q, q̇, q̈), so no model file
holds them and no worker runs them as a feed-forward.

Both learn what the rigid prior leaves of the motors' torque (friction, the true masses, the
payload), as the residual network does, so they are compared on the same footing:

- gp: scikit-learn's exact Gaussian process (an ARD squared-exponential kernel and white noise)
  on GP_POINTS training rows drawn at random: the subset-of-data approximation. Its 23
  hyperparameters are chosen by maximum marginal likelihood on the first GP_TUNE_POINTS of them:
  the likelihood's gradient needs O(m²) memory per hyperparameter and many O(m³) solves, some
  8 minutes at 1,000 rows, where inference with them fixed is one solve.
- history: the residual network with, as further inputs, q̇ and q̈ of the HISTORY_LAGS ticks
  before (within the episode; an episode's first ticks repeat its first): what a delay, a
  spring's lag behind the motor or a friction's hysteresis would leave to learn.
"""

import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gainfarm.analytic.data.learning import (
    BENCHMARK,
    LearnError,
    Rows,
    fit,
    fit_network,
    floor_model,
    no_rows,
    plants,
    read_split,
    read_splits,
    rigid_prior,
    score_rows,
)
from gainfarm.analytic.data.loader import VARIANTS
from gainfarm.models.dynamics import DynamicsModel, Network

GP_POINTS = 3000
GP_TUNE_POINTS = 300
GP_CHUNK = 5_000  # rows predicted at a time: the (rows, GP_POINTS) kernel block stays 120 MB
HISTORY_LAGS = (1, 2, 3, 4)  # ticks: 2 to 8 ms back


@dataclass(frozen=True, eq=False)
class GaussianProcess:
    """The rigid prior plus a Gaussian process of its residual."""

    prior: DynamicsModel
    process: Any  # sklearn.gaussian_process.GaussianProcessRegressor, fitted
    input_mean: np.ndarray
    input_scale: np.ndarray
    about: dict[str, Any]
    kind: str = "gp"
    target: str = "inverse"

    def predict_rows(self, rows: Rows) -> np.ndarray:
        inputs = rows.inputs("inverse")
        x = (np.hstack(inputs) - self.input_mean) / self.input_scale
        residual = np.vstack(
            [self.process.predict(x[k : k + GP_CHUNK]) for k in range(0, len(x), GP_CHUNK)]
        )
        return self.prior.predict(*inputs) + residual


@dataclass(frozen=True, eq=False)
class History:
    """The rigid prior plus a network of its residual from this tick and the last few."""

    prior: DynamicsModel
    network: Network
    about: dict[str, Any]
    kind: str = "history"
    target: str = "inverse"

    def predict_rows(self, rows: Rows) -> np.ndarray:
        return self.prior.predict(*rows.inputs("inverse")) + self.network(history_inputs(rows))


def fit_gp(prior: DynamicsModel, train: Rows, seed: int) -> GaussianProcess:
    """A Gaussian process of the prior's residual on GP_POINTS random training rows."""
    try:  # optional extra: learn
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
    except ImportError:
        raise LearnError(
            "a Gaussian process needs scikit-learn: pip install 'gainfarm[learn]'"
        ) from None
    rng = np.random.default_rng(seed)
    chosen = rng.choice(len(train), size=min(GP_POINTS, len(train)), replace=False)
    inputs = [signal[chosen] for signal in train.inputs("inverse")]
    x = np.hstack(inputs)
    mean, scale = x.mean(axis=0), np.where(x.std(axis=0) > 1e-12, x.std(axis=0), 1.0)
    residual = train.u[chosen] - prior.predict(*inputs)
    x = (x - mean) / scale
    kernel = ConstantKernel(1.0) * RBF(np.ones(x.shape[1]), (1e-2, 1e3)) + WhiteKernel(1e-2)
    tune = GP_TUNE_POINTS  # the draw is random, so its first rows are a random subset too
    with warnings.catch_warnings():  # a length scale at its bound is an irrelevant input: fine
        warnings.simplefilter("ignore", ConvergenceWarning)
        tuned = GaussianProcessRegressor(kernel, normalize_y=True, random_state=seed)
        tuned.fit(x[:tune], residual[:tune])
    process = GaussianProcessRegressor(tuned.kernel_, normalize_y=True, optimizer=None)
    process.fit(x, residual)
    about = {
        "points": len(chosen),
        "tuned_on": min(tune, len(chosen)),
        "kernel": str(tuned.kernel_),
    }
    return GaussianProcess(prior, process, mean, scale, about)


def fit_history(prior: DynamicsModel, train: Rows, validation: Rows, seed: int) -> History:
    """A residual network on this tick's (q, q̇, q̈) and the HISTORY_LAGS ticks' (q̇, q̈)."""

    def data(rows: Rows) -> tuple[np.ndarray, np.ndarray]:
        return history_inputs(rows), rows.u - prior.predict(*rows.inputs("inverse"))

    check = data(validation) if len(validation) else None
    network, notes = fit_network(*data(train), check, seed)
    return History(prior, network, notes | {"lags": list(HISTORY_LAGS)})


def history_inputs(rows: Rows) -> np.ndarray:
    """(n, 21 + 14·len(HISTORY_LAGS)): q, q̇, q̈ of each row, then q̇ and q̈ of the row `lag`
    ticks before in its episode (its first row where there is none). Rows are in episode order,
    each episode's ticks in time order, as a split is read."""
    n = len(rows)
    index = np.arange(n)
    starts = np.ones(n, dtype=bool)
    starts[1:] = (rows.episode_id[1:] != rows.episode_id[:-1]) | (np.diff(rows.t) <= 0)
    first = np.maximum.accumulate(np.where(starts, index, 0))
    columns = [rows.q, rows.qd, rows.qdd]
    for lag in HISTORY_LAGS:
        earlier = np.maximum(index - lag, first)
        columns += [rows.qd[earlier], rows.qdd[earlier]]
    return np.hstack(columns)


def benchmark(
    dataset_dir: Path, seed: int = 0, kinds: tuple[str, ...] = BENCHMARK
) -> dict[str, dict[str, Any]]:
    """Every model of `kinds` (inverse dynamics) fitted on the dataset's train split and scored
    on its test split (`score_rows`: all and calm), with its fit's seconds, and under "variants"
    on test_variants if the dataset has it: the baseline table of a release. The splits are
    read once. Raises LearnError, one line."""
    splits = read_splits(dataset_dir)
    test = splits["test"]
    if not len(test):
        raise LearnError(no_rows(dataset_dir, "test"))
    train = splits["train"] if len(splits["train"]) else test
    variants = read_split(dataset_dir, "test" + VARIANTS)
    prior = rigid_prior(plants(dataset_dir)[0])
    table = {}
    for kind in kinds:
        started = time.perf_counter()
        model: Any
        if kind == "plant":  # each episode's own plant: the floor of a dataset of variants too
            model = floor_model(dataset_dir)
        elif kind == "gp":
            model = fit_gp(prior, splits["train"], seed)
        elif kind == "history":
            model = fit_history(prior, splits["train"], splits["validation"], seed)
        else:
            model = fit(dataset_dir, "inverse", kind, seed, splits)  # type: ignore[arg-type]
        seconds = time.perf_counter() - started
        table[kind] = score_rows(model, test, train) | {"fit_seconds": round(seconds, 3)}
        if len(variants):  # the same model on the other plants: what it cannot know
            table[kind]["variants"] = score_rows(model, variants, train)
    return table
