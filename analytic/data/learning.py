"""Learning the arm's dynamics from a dataset (analytic/dataset.py): fit, score, report.

`learn` trains one model (models/dynamics.py) on the dataset's "train" split, chooses the
network's epoch on "validation", scores it on "test" and writes a model directory:

    model.npz        the model file (what a worker's feed-forward loads, named by its SHA-256)
    scores.json      nMSE and RMSE per joint on the test split
    report.md        what was trained on what, the scores, the plot
    prediction.png   predicted against measured, one test episode, one panel per joint

The directory appears whole or not at all. Networks are scikit-learn's MLPRegressor: a
well-kept library of modest size. PyTorch would be the field's usual choice, but its wheels are
gigabytes, for networks this small (3 × 128 units, tens of thousands of rows) on a CPU.
"""

import dataclasses
import json
import math
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from scipy.optimize import minimize

from gainfarm.analytic.data.dataset_columns import JOINTS_BEFORE
from gainfarm.analytic.data.learning_report import (
    MEAN_JOINTS as MEAN_JOINTS,  # where the experiments import it from
)
from gainfarm.analytic.data.learning_report import (
    PUBLISHED_JOINTS,
    anchors_table,
    mean_joints,
    scores_table,
    span,
    what,
)
from gainfarm.analytic.data.loader import EPISODES, SPLITS, TICKS, VARIANTS, dataset_arm
from gainfarm.analytic.view.figures import DPI, save_png
from gainfarm.analytic.view.reports import plant_text
from gainfarm.edges.files import staging_directory, write_atomically
from gainfarm.models.dynamics import (
    KINDS,
    MODEL_FILE,
    TARGETS,
    DynamicsModel,
    Kind,
    Network,
    Target,
    WrongRobot,
    check_robot,
    consistent_coordinates,
    digest,
    from_consistent,
    inconsistencies,
    joint_names,
    nearest_consistent,
    physical_parameters,
    regressor,
    rigid_prior,
    rigid_spec,
    to_bytes,
    true_model,
)
from gainfarm.schemas.robot import PlantSpec

# The whole motor torque a model of the arm learns (dataset version 3); a dataset from before it
# has only u, the motor torque of its episodes, all on a plain torque interface.
MOTOR_TORQUE, COMMAND = "u_motor", "u"
# The acceleration a model learns from and is scored on: the Savitzky-Golay fit's (dataset
# version 4), whose noise leaves the true model nMSE 0.001 where the difference's leaves 0.09
# (analytic.data.dataset.SG_WINDOW); a dataset from before it has only the difference.
ACCELERATION, DIFFERENCED = "qdd_sg", "qdd"
UNITS = {"inverse": "N·m", "forward": "rad/s²"}
SCORES_FILE = "scores.json"
REPORT_FILE = "report.md"
PLOT_FILE = "prediction.png"

# The network and its training. Epochs are counted, not timed, so a seed gives one model on any
# machine; ROW_PASSES bounds the work: 16 epochs of a 1.1-million-row train split. On such a
# release the networks took 147 s (MLP) to 224 s (history) on 2 cores, stopped early on their
# validation loss (docs/dataset.md, "A release of a million ticks").
HIDDEN_LAYERS = (128, 128, 128)
BATCH_SIZE = 256
LEARNING_RATE = 1e-3
# sklearn's alpha: L2 penalty 0.5·alpha·|W|² per mini-batch of BATCH_SIZE rows. Strong, because
# a dataset holds few trajectories, each a thin curve through the 21 inputs, and a lightly
# penalised network memorises them: at 1e-5 the validation loss is lowest after the first epoch
# and the test nMSE stays near 0.2. Measured on 20 realistic-plant fourier episodes (60,000
# rows), 40 epochs: alpha 1, 3, 10 gave test nmse_mean 0.21, 0.072, 0.094 (residual) and 0.31,
# 0.12, 0.17 (mlp). More rows need less: the penalty falls as 1 / rows beyond L2_ROWS (on 380,000
# rows of a tuned front, alpha 0.1 gave the residual network 0.0085 where 3 gave 0.032).
L2_PENALTY = 3.0
L2_ROWS = 60_000
MAX_EPOCHS = 60
MIN_EPOCHS = 8
ROW_PASSES = 18_000_000  # epochs × training rows, at most
PATIENCE = 10  # epochs without a better validation loss before stopping

# Identification: rows regressed at a time (the regressor is 7 × 91 floats a row on the iiwa), the
# smallest singular value kept, relative to the largest, of the column-scaled regressor (as
# numpy's lstsq rcond): directions the data do not excite stay at the documented arm's values.
REGRESSOR_CHUNK = 4000
RCOND = 1e-6
# The consistent fit's L-BFGS: some 850 iterations and 4 s on a tuned front's normal equations.
CONSISTENT_SEARCH = {"maxiter": 20_000, "maxfun": 40_000}


class LearnError(ValueError):
    """The dataset or the request cannot give a model; the message is one line for the user."""


class OutUnwritable(LearnError):
    """The model directory cannot be written there: the command names its option."""


@dataclass(frozen=True)
class Rows:
    """The ticks of one split with a finite acceleration, as (n, N) arrays (N the arm's joints,
    `joints`) and (n,) identifiers."""

    episode_id: np.ndarray  # (n,) str
    t: np.ndarray  # (n,) s since the episode started
    q: np.ndarray  # rad, measured link side
    qd: np.ndarray  # rad/s
    qdd: np.ndarray  # rad/s²: the dataset's qdd_sg (Savitzky-Golay), or qdd before it
    u: np.ndarray  # N·m, the motors' whole torque as applied (the dataset's u_motor)
    calm: np.ndarray  # (n,) bool: the tick's episode is calm (every one, before the flag)
    joints: tuple[str, ...] = JOINTS_BEFORE  # the arm's joints, the arrays' columns

    def __len__(self) -> int:
        return len(self.t)

    def take(self, index: np.ndarray) -> "Rows":
        """The rows at `index` (positions or a mask), every array alike."""
        arrays = {name: getattr(self, name)[index] for name in _ARRAYS}
        return Rows(**arrays, joints=self.joints)

    @staticmethod
    def concatenate(parts: "Sequence[Rows]") -> "Rows":
        """`parts`' rows one after the other, every array alike: of one arm."""
        joints = {part.joints for part in parts}
        if len(joints) > 1:
            raise LearnError(f"rows of {len(joints)} arms' joints cannot be put together")
        arrays = {n: np.concatenate([getattr(part, n) for part in parts]) for n in _ARRAYS}
        return Rows(**arrays, joints=parts[0].joints)

    def inputs(self, target: Target) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, q̇, q̈) for an inverse model, (q, q̇, u) for a forward one."""
        return (self.q, self.qd, self.qdd if target == "inverse" else self.u)

    def output(self, target: Target) -> np.ndarray:
        """What a `target` model predicts: u, or q̈."""
        return self.u if target == "inverse" else self.qdd


_ARRAYS = tuple(field.name for field in dataclasses.fields(Rows) if field.name != "joints")


def arm(dataset_dir: Path) -> tuple[str, tuple[str, ...]]:
    """The dataset's robot and its joints (loader.dataset_arm); LearnError, one line."""
    try:
        return dataset_arm(Path(dataset_dir))
    except FileNotFoundError:
        raise LearnError(f"{str(dataset_dir)!r} holds no dataset (no {TICKS})") from None
    except (OSError, pa.ArrowException, ValueError) as error:
        raise LearnError(f"{str(dataset_dir)!r}: unreadable {TICKS}: {_one_line(error)}") from None


def read_split(dataset_dir: Path, split: str) -> Rows:
    """The rows of `split` ("train", "validation", "test"), last ticks (no q̈) dropped; `u` is
    the motors' whole torque (`u_motor`, or `u` in a dataset from before it).

    Raises LearnError, one line, if the dataset is missing or lacks the columns."""
    torque = motor_torque_column(dataset_dir)
    acceleration = acceleration_column(dataset_dir)
    _, joints = arm(dataset_dir)
    signals = {"q": "q", "qd": "qd", "qdd": acceleration, "u": torque}  # Rows' → the column's
    columns = ["episode_id", "t"] + [f"{c}_{j}" for c in signals.values() for j in joints]
    try:
        table = pq.read_table(
            Path(dataset_dir) / TICKS, columns=columns, filters=[("split", "==", split)]
        )
    except FileNotFoundError:
        raise LearnError(f"{str(dataset_dir)!r} holds no dataset (no {TICKS})") from None
    except (OSError, pa.ArrowException, ValueError, KeyError) as error:
        raise LearnError(f"{str(dataset_dir)!r}: unreadable {TICKS}: {_one_line(error)}") from None
    arrays = {
        s: np.column_stack([table[f"{c}_{j}"].to_numpy() for j in joints]).astype(float)
        if table.num_rows
        else np.empty((0, len(joints)))
        for s, c in signals.items()
    }
    finite = np.isfinite(np.hstack(list(arrays.values()))).all(axis=1)
    episode_id = table["episode_id"].to_numpy(zero_copy_only=False)[finite].astype(str)
    rough = rough_episodes(dataset_dir)
    return Rows(
        episode_id=episode_id,
        t=table["t"].to_numpy()[finite].astype(float),
        calm=~np.isin(episode_id, list(rough)) if rough else np.ones(len(episode_id), bool),
        **{s: arrays[s][finite] for s in signals},
        joints=joints,
    )


def acceleration_column(dataset_dir: Path) -> str:
    """The acceleration a model learns from: `qdd_sg` (dataset version 4), or `qdd` before it."""
    names = _tick_names(dataset_dir)
    first = arm(dataset_dir)[1][0]
    return ACCELERATION if f"{ACCELERATION}_{first}" in names else DIFFERENCED


def rough_episodes(dataset_dir: Path) -> set[str]:
    """The ids of the episodes that are not calm (`calm` false in episodes.parquet); none in a
    dataset from before the flag."""
    try:
        names = pq.read_schema(Path(dataset_dir) / EPISODES).names
        if "calm" not in names:
            return set()
        table = pq.read_table(Path(dataset_dir) / EPISODES, columns=["episode_id", "calm"])
    except FileNotFoundError:
        raise LearnError(f"{str(dataset_dir)!r} holds no dataset (no {EPISODES})") from None
    except (OSError, pa.ArrowException, ValueError) as error:
        raise LearnError(
            f"{str(dataset_dir)!r}: unreadable {EPISODES}: {_one_line(error)}"
        ) from None
    ids, calm = table["episode_id"].to_pylist(), table["calm"].to_pylist()
    return {str(episode) for episode, ok in zip(ids, calm, strict=True) if not ok}


def _tick_names(dataset_dir: Path) -> list[str]:
    try:
        return pq.read_schema(Path(dataset_dir) / TICKS).names
    except FileNotFoundError:
        raise LearnError(f"{str(dataset_dir)!r} holds no dataset (no {TICKS})") from None
    except (OSError, pa.ArrowException, ValueError) as error:
        raise LearnError(f"{str(dataset_dir)!r}: unreadable {TICKS}: {_one_line(error)}") from None


def motor_torque_column(dataset_dir: Path) -> str:
    """The column of the motors' whole torque: `u_motor`, or in a dataset from before it `u`,
    which was the motor torque only if every episode commanded it (a plain torque interface;
    behind FRI the robot adds its gravity model to u). LearnError, one line, if it was not."""
    names = _tick_names(dataset_dir)
    if f"{MOTOR_TORQUE}_{arm(dataset_dir)[1][0]}" in names:
        return MOTOR_TORQUE
    if any(plant.interface == "fri" for plant in plants(dataset_dir)):
        raise LearnError(
            f"{str(dataset_dir)!r} has no {MOTOR_TORQUE} column and holds episodes behind FRI, "
            "whose u leaves out the robot's gravity compensation: build it again with "
            "analytic dataset"
        )
    return COMMAND


@dataclass(frozen=True, eq=False)
class Floor:
    """The floor of a dataset: each episode's rows predicted by its own plant's dynamics
    (`true_model`), so a dataset of several plants (`analytic dataset --plants`) has one too."""

    plant_of: dict[str, PlantSpec]  # episode id → its plant
    target: Target = "inverse"
    kind: str = "plant"

    def predict_rows(self, rows: Rows) -> np.ndarray:
        predicted = np.empty_like(rows.output(self.target))
        for plant in {self.plant_of[episode] for episode in set(rows.episode_id)}:
            mine = np.isin(rows.episode_id, [e for e, p in self.plant_of.items() if p == plant])
            inputs = (signal[mine] for signal in rows.inputs(self.target))
            predicted[mine] = true_model(plant, self.target).predict(*inputs)
        return predicted


def floor_model(dataset_dir: Path, target: Target = "inverse") -> Floor:
    """The dataset's floor (`Floor`), from its episodes' `model` column."""
    try:
        table = pq.read_table(Path(dataset_dir) / EPISODES, columns=["episode_id", "model"])
        texts = dict(zip(table["episode_id"].to_pylist(), table["model"].to_pylist(), strict=True))
        specs = {text: PlantSpec.model_validate_json(text) for text in set(texts.values())}
    except (OSError, pa.ArrowException, ValueError, KeyError) as error:
        raise LearnError(
            f"{str(dataset_dir)!r}: unreadable {EPISODES}: {_one_line(error)}"
        ) from None
    return Floor({str(episode): specs[text] for episode, text in texts.items()}, target)


def plants(dataset_dir: Path, variants: bool = False) -> list[PlantSpec]:
    """The distinct plants of the dataset's episodes in train, validation and test (the runs'
    own), in order of first appearance; with `variants`, those of the *_variants splits (none
    in a dataset without them)."""
    try:
        table = pq.read_table(Path(dataset_dir) / EPISODES)
        texts = table["model"].to_pylist()
        parts = table["split"].to_pylist() if "split" in table.column_names else None
    except FileNotFoundError:
        raise LearnError(f"{str(dataset_dir)!r} holds no dataset (no {EPISODES})") from None
    except (OSError, pa.ArrowException, ValueError, KeyError, TypeError) as error:
        raise LearnError(
            f"{str(dataset_dir)!r}: unreadable {EPISODES}: {_one_line(error)}"
        ) from None
    if parts is not None:
        texts = [t for t, p in zip(texts, parts, strict=True) if p.endswith(VARIANTS) == variants]
    found: list[PlantSpec] = []
    try:
        for text in texts:
            plant = PlantSpec.model_validate_json(text)
            if plant not in found:
                found.append(plant)
    except ValueError as error:
        raise LearnError(
            f"{str(dataset_dir)!r}: unreadable {EPISODES}: {_one_line(error)}"
        ) from None
    if not found and not variants:
        raise LearnError(f"{str(dataset_dir)!r}: {EPISODES} lists no episodes")
    return found


def read_splits(dataset_dir: Path) -> dict[str, Rows]:
    """Every split's rows, read once (a million ticks take seconds to read)."""
    return {split: read_split(dataset_dir, split) for split in SPLITS}


def fit(
    dataset_dir: Path,
    target: Target,
    kind: Kind,
    seed: int = 0,
    splits: dict[str, Rows] | None = None,
) -> DynamicsModel:
    """A `kind` model of `target` dynamics, trained on the dataset's "train" split (the
    network's epoch chosen on "validation"); the physics uses the first episode's plant.
    `splits` are the dataset's rows if already read (`read_splits`)."""
    if target not in TARGETS:
        raise LearnError(f"unknown target {target!r}: one of {', '.join(TARGETS)}")
    if kind not in KINDS:
        raise LearnError(f"unknown model {kind!r}: one of {', '.join(KINDS)}")
    if kind == "linear" and target == "forward":
        raise LearnError(
            "a linear model is inverse only (its identified inertia need not invert): "
            "use --target inverse, or --kind mlp or residual for forward dynamics"
        )
    plant = plants(dataset_dir)[0]
    prior = rigid_prior(plant, target)
    if kind == "rigid":
        return prior
    if kind == "plant":  # the simulated plant's own dynamics: the anchor, nothing to learn
        return true_model(plant, target)
    train = splits["train"] if splits else read_split(dataset_dir, "train")
    if not len(train):
        raise LearnError(f"{str(dataset_dir)!r}: the dataset has no rows in its train split")
    about: dict[str, Any] = {
        "dataset": Path(dataset_dir).resolve().name,
        "plant": json.loads(plant.model_dump_json()),
        "train_rows": len(train),
        "seed": seed,
    }
    if kind == "linear":
        try:
            parameters, rank, notes = identify(prior.spec, train)
        except ImportError as error:  # Pinocchio is optional: gainfarm[learn]
            raise LearnError(str(error)) from None
        about["identified_rank"] = rank
        about["inconsistencies"] = inconsistencies(parameters, joint_names(prior.spec))
        about |= notes
        return DynamicsModel(
            kind=kind, target=target, spec=prior.spec, parameters=parameters, about=about
        )
    validation = splits["validation"] if splits else read_split(dataset_dir, "validation")
    about["validation_rows"] = len(validation)
    subtract = prior if kind == "residual" else None
    network, training = train_network(train, validation, target, subtract, seed)
    return DynamicsModel(
        kind=kind, target=target, spec=prior.spec, network=network, about=about | training
    )


def identify(spec: PlantSpec, rows: Rows) -> tuple[np.ndarray, int, dict[str, Any]]:
    """π of the linear model, physically consistent; how many directions of it the data
    determine; and what the consistency cost.

    First least squares for the change from the documented arm's π₀ (`physical_parameters`):
    the smallest change that explains u, so the directions the motion does not excite (a link's
    mass about a vertical axis, say) keep their physical values instead of zero. The normal
    equations are accumulated in chunks (the full regressor of 60,000 rows is 300 MB) and solved
    by an eigendecomposition with columns scaled to unit norm, which gives numpy lstsq's
    minimum-norm solution with rcond = RCOND. That π predicts well but is rarely an arm (on a
    tuned front's data, five of seven links had no physical body), so it is then the start of
    the same least squares over consistent arms only (`from_consistent`: each link's
    log-Cholesky factor, positive friction and rotor inertia), by L-BFGS on the normal
    equations, with a ridge of the size RCOND cuts at keeping the unexcited directions put."""
    start = physical_parameters(spec)
    gram = np.zeros((start.size, start.size))
    moment = np.zeros(start.size)
    for begin in range(0, len(rows), REGRESSOR_CHUNK):
        chunk = slice(begin, begin + REGRESSOR_CHUNK)
        y = regressor(spec, rows.q[chunk], rows.qd[chunk], rows.qdd[chunk])
        y = y.reshape(-1, start.size)
        residual = rows.u[chunk].reshape(-1) - y @ start
        gram += y.T @ y
        moment += y.T @ residual
    norms = np.sqrt(np.diag(gram))
    scale = np.where(norms > 0, norms, 1.0)
    scaled_gram, scaled_moment = gram / np.outer(scale, scale), moment / scale
    values, vectors = np.linalg.eigh(scaled_gram)
    # Singular values of the scaled regressor are the square roots of these eigenvalues.
    kept = values > (RCOND**2) * values.max()
    projected = vectors[:, kept].T @ scaled_moment
    free = start + vectors[:, kept] @ (projected / values[kept]) / scale
    ridge = (RCOND**2) * values.max()

    def change(parameters: np.ndarray) -> np.ndarray:
        return (parameters - start) * scale

    def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
        """|Y π − u|² − |Y π₀ − u|², plus the ridge, and its gradient in θ."""
        parameters, jacobian = from_consistent(theta)
        step = change(parameters)
        pull = scaled_gram @ step - scaled_moment + ridge * step
        value = step @ (scaled_gram @ step) - 2 * scaled_moment @ step + ridge * step @ step
        return float(value), jacobian.T @ (2 * pull * scale)

    flaws = inconsistencies(free, joint_names(spec))
    if flaws:
        theta = consistent_coordinates(nearest_consistent(free))
        solution = minimize(
            objective, theta, jac=True, method="L-BFGS-B", options=CONSISTENT_SEARCH
        )
        parameters, _ = from_consistent(solution.x)
    else:
        parameters = free

    def explained(candidate: np.ndarray) -> float:  # the fall of |Y π − u|² from π₀'s
        step = change(candidate)
        return float(2 * scaled_moment @ step - step @ (scaled_gram @ step))

    cost = 1.0 - explained(parameters) / explained(free) if explained(free) > 0 else 0.0
    notes = {"unconstrained_flaws": flaws, "consistency_cost": cost}
    return parameters, int(kept.sum()), notes


def train_network(
    train: Rows,
    validation: Rows,
    target: Target,
    prior: DynamicsModel | None,
    seed: int,
) -> tuple[Network, dict[str, Any]]:
    """A network of `target` (of what `prior` leaves of it, if given) and how it was trained
    (`fit_network`)."""
    x_train, y_train = _network_data(train, target, prior)
    check = _network_data(validation, target, prior) if len(validation) else None
    return fit_network(x_train, y_train, check, seed)


def fit_network(
    x_train: np.ndarray,
    y_train: np.ndarray,
    check: tuple[np.ndarray, np.ndarray] | None,
    seed: int,
) -> tuple[Network, dict[str, Any]]:
    """A network from inputs to outputs, and how it was trained.

    Adam on mini-batches, one epoch per partial_fit, keeping the weights of the epoch with the
    lowest loss on `check` (the validation rows); without them, the lowest training loss (said
    in the returned notes). Inputs and outputs are standardised on the training rows."""
    input_mean, input_scale = _standardisation(x_train)
    output_mean, output_scale = _standardisation(y_train)
    # Single precision: half the time of each epoch's products, and the signals' noise is far
    # above its 1e-7 rounding.
    xs = ((x_train - input_mean) / input_scale).astype(np.float32)
    ys = ((y_train - output_mean) / output_scale).astype(np.float32)
    if check is not None:
        x_check, y_check = check
        xv = ((x_check - input_mean) / input_scale).astype(np.float32)
        yv = ((y_check - output_mean) / output_scale).astype(np.float32)
        chosen_on = "validation"
    else:
        xv, yv, chosen_on = xs, ys, "train (the dataset has no validation split)"
    try:  # optional extra: learn
        from sklearn.neural_network import MLPRegressor
        from threadpoolctl import threadpool_limits
    except ImportError:
        raise LearnError(
            "training a network needs scikit-learn: pip install 'gainfarm[learn]'"
        ) from None
    network = MLPRegressor(
        hidden_layer_sizes=HIDDEN_LAYERS,
        activation="relu",
        solver="adam",
        alpha=l2_penalty(len(xs)),
        batch_size=BATCH_SIZE,
        learning_rate_init=LEARNING_RATE,
        shuffle=True,
        random_state=seed,
    )
    epochs = int(min(MAX_EPOCHS, max(MIN_EPOCHS, ROW_PASSES // len(xs))))
    best_loss, best_epoch, best = math.inf, 0, None
    # One BLAS thread: this network's products are too small to gain from more (a residual
    # network on 32,000 rows trained in 20.4 s on two threads, 19.2 s on one), and beside another
    # busy process OpenBLAS's spinning threads contend: on two cores, two fits of 3,600 rows at
    # once took 9.7 s each on two threads, 2.4-2.8 s on one (2.7 s alone).
    with threadpool_limits(1):
        for epoch in range(1, epochs + 1):
            network.partial_fit(xs, ys)
            loss = float(np.mean((network.predict(xv).reshape(len(xv), -1) - yv) ** 2))
            if loss < best_loss:
                best_loss, best_epoch = loss, epoch
                best = (
                    [w.copy() for w in network.coefs_],
                    [b.copy() for b in network.intercepts_],
                )
            elif epoch - best_epoch >= PATIENCE:
                break
    assert best is not None  # the first epoch's loss is finite or the data are
    weights, biases = best
    learned = Network(
        weights=tuple(w.astype(np.float64) for w in weights),
        biases=tuple(b.astype(np.float64) for b in biases),
        input_mean=input_mean,
        input_scale=input_scale,
        output_mean=output_mean,
        output_scale=output_scale,
        activation="relu",
    )
    notes = {
        "hidden_layers": list(HIDDEN_LAYERS),
        "epochs_run": epoch,
        "best_epoch": best_epoch,
        "best_loss": best_loss,
        "chosen_on": chosen_on,
    }
    return learned, notes


def l2_penalty(rows: int) -> float:
    """sklearn's alpha for `rows` training rows: L2_PENALTY up to L2_ROWS, then ∝ 1 / rows."""
    return L2_PENALTY * min(1.0, L2_ROWS / max(rows, 1))


def _network_data(
    rows: Rows, target: Target, prior: DynamicsModel | None
) -> tuple[np.ndarray, np.ndarray]:
    inputs = rows.inputs(target)
    output = rows.output(target)
    if prior is not None:
        output = output - prior.predict(*inputs)
    return np.hstack(inputs), output


def _standardisation(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = values.mean(axis=0)
    scale = values.std(axis=0)
    # A constant column (a joint that never moved) is centred, not divided by zero.
    return mean, np.where(scale > 1e-12, scale, 1.0)


def score(model: DynamicsModel, dataset_dir: Path, split: str = "test") -> dict[str, Any]:
    """How well `model` predicts its target on `split`, on all its rows and on its calm
    episodes' ("calm", the same keys): per joint nMSE (MSE over the variance of the measured
    target) and RMSE; the nMSE's mean over all joints but the flange's (A1..A6 on the iiwa 14:
    "nmse_mean") and over all, the RMSE's over the first four (A1..A4, "rmse_a1_a4", the joints
    published figures give); and the nMSE of predicting the training split's mean, the baseline
    (about 1). LearnError, one line, if `model` is of another arm than the dataset."""
    try:  # even of as many joints, another arm's model computes torques for other links
        check_robot(model, arm(dataset_dir)[0])
    except WrongRobot as error:
        raise LearnError(f"{str(dataset_dir)!r}: {error}") from None
    rows = read_split(dataset_dir, split)
    if not len(rows):
        raise LearnError(no_rows(dataset_dir, split))
    train = read_split(dataset_dir, "train")
    return score_rows(model, rows, train if len(train) else rows) | {"split": split}


def score_rows(model: Any, rows: Rows, train: Rows) -> dict[str, Any]:
    """`score` on rows in memory; `train` gives the mean predictor's constant. `model` is a
    DynamicsModel, or a baseline that predicts from rows (analytic.data.baselines)."""
    measured = rows.output(model.target)
    if hasattr(model, "predict_rows"):
        predicted = model.predict_rows(rows)
    else:
        predicted = model.predict(*rows.inputs(model.target))
    baseline = train.output(model.target).mean(axis=0)
    joints = rows.joints
    everything = _errors(measured, predicted, baseline, joints)
    calm = (
        _errors(measured[rows.calm], predicted[rows.calm], baseline, joints)
        if rows.calm.any()
        else None
    )
    return {
        "kind": model.kind,
        "target": model.target,
        "unit": UNITS[model.target],
        **everything,
        "calm": calm,
    }


def _errors(
    measured: np.ndarray, predicted: np.ndarray, baseline: np.ndarray, joints: Sequence[str]
) -> dict[str, Any]:
    variance = measured.var(axis=0)
    mse = ((predicted - measured) ** 2).mean(axis=0)
    nmse = _per_joint(mse / variance, joints)
    baseline_nmse = ((measured - baseline) ** 2).mean(axis=0) / variance
    averaged = mean_joints(joints)
    return {
        "rows": len(measured),
        "nmse": nmse,
        "rmse": _per_joint(np.sqrt(mse), joints),
        "variance": _per_joint(variance, joints),
        "nmse_mean": float(np.mean([nmse[j] for j in averaged])),
        "nmse_mean_all": float(np.mean(list(nmse.values()))),
        "rmse_a1_a4": float(np.mean(np.sqrt(mse[:PUBLISHED_JOINTS]))),
        "mean_predictor_nmse": float(np.mean(baseline_nmse[: len(averaged)])),
    }


def learn(
    dataset_dir: Path,
    out_dir: Path,
    target: Target = "inverse",
    kind: Kind = "residual",
    seed: int = 0,
) -> dict[str, Any]:
    """Fit a `kind` model of `target` dynamics on `dataset_dir`, score it on its test split and
    write `out_dir` (model.npz, scores.json, report.md, prediction.png), whole or not at all;
    return the scores. `out_dir` must not exist. Raises LearnError, one line."""
    dataset_dir, out_dir = Path(dataset_dir), Path(out_dir)
    if out_dir.exists():
        raise OutUnwritable(f"{str(out_dir)!r} already exists")
    # Found before the fit, which may take minutes, rather than when its files are written.
    ancestor = next((parent for parent in out_dir.parents if parent.exists()), None)
    if ancestor is not None and not ancestor.is_dir():
        raise OutUnwritable(f"cannot write {str(out_dir)!r}: {str(ancestor)!r} is a file")
    if kind == "linear" and target == "forward":
        fit(dataset_dir, target, kind, seed)  # raises the one explanation
    found = plants(dataset_dir)
    splits = read_splits(dataset_dir)
    test = splits["test"]
    if not len(test):
        raise LearnError(no_rows(dataset_dir, "test"))
    started = time.perf_counter()
    model = fit(dataset_dir, target, kind, seed, splits)
    seconds = time.perf_counter() - started
    raw = to_bytes(model)
    train = splits["train"] if len(splits["train"]) else test
    scores = score_rows(model, test, train) | {
        "split": "test",
        "acceleration": acceleration_column(dataset_dir),
        "fit_seconds": round(seconds, 3),
        "seed": seed,
        "digest": digest(raw),
        # The anchors on the same rows: no learned model can beat the plant's own dynamics
        # but by chance, and one that does not beat the untrained rigid prior learned nothing.
        "floor": score_rows(floor_model(dataset_dir, target), test, train),
        "prior": score_rows(rigid_prior(found[0], target), test, train),
    }
    counts = {split: _episode_count(rows) for split, rows in splits.items()}
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        staging = staging_directory(out_dir)
    except OSError as error:
        raise OutUnwritable(f"cannot write {str(out_dir)!r}: {error.strerror}") from None
    try:
        write_atomically(staging / MODEL_FILE, raw)
        write_atomically(staging / SCORES_FILE, (json.dumps(scores, indent=2) + "\n").encode())
        plot_prediction(staging / PLOT_FILE, model, test)
        text = report(dataset_dir, model, scores, found, counts)
        write_atomically(staging / REPORT_FILE, text.encode())
        if out_dir.exists():  # made while we trained: never replaced
            raise OutUnwritable(f"{str(out_dir)!r} already exists")
        staging.rename(out_dir)
    except OSError as error:
        shutil.rmtree(staging, ignore_errors=True)
        raise OutUnwritable(f"cannot write {str(out_dir)!r}: {error.strerror}") from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return scores


# The baselines of a benchmark table, in its order: the two untrained anchors (the floor, the
# prior), then what a dynamics researcher trains beside them.
BENCHMARK: tuple[str, ...] = ("plant", "rigid", "linear", "mlp", "residual", "gp", "history")


def plot_prediction(path: Path, model: DynamicsModel, rows: Rows) -> None:
    """Predicted against measured over time for the first episode of `rows`, one panel a joint."""
    episode = sorted(set(rows.episode_id))[0]
    mine = rows.episode_id == episode
    inputs = tuple(signal[mine] for signal in rows.inputs(model.target))
    measured, predicted = rows.output(model.target)[mine], model.predict(*inputs)
    t = rows.t[mine]
    figure = Figure(figsize=(9.0, 10.0), dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)  # Agg explicitly, as analytic/figures.py: no backend, no display
    panels = figure.subplots(4, 2, sharex=True).ravel()
    quantity = "motor torque" if model.target == "inverse" else "q̈"
    for index, (axes, joint) in enumerate(zip(panels, rows.joints, strict=False)):
        axes.plot(t, measured[:, index], color="black", linewidth=0.8, label="measured")
        axes.plot(t, predicted[:, index], color="tab:orange", linewidth=0.8, label="predicted")
        axes.set_title(joint, fontsize=9)
        axes.set_ylabel(f"{quantity} ({UNITS[model.target]})", fontsize=8)
        axes.grid(True, alpha=0.3)
    panels[0].legend(loc="upper right", fontsize=8)
    used = min(len(rows.joints), len(panels))
    for axes in panels[used:]:
        axes.axis("off")
    for axes in panels[max(used - 2, 0) : used]:  # each column's lowest panel in use
        axes.xaxis.set_tick_params(labelbottom=True)
        axes.set_xlabel("t (s)")
    figure.suptitle(f"{model.kind} {model.target} model on test episode {episode}", fontsize=10)
    save_png(figure, path)


def report(
    dataset_dir: Path,
    model: DynamicsModel,
    scores: dict[str, Any],
    found: list[PlantSpec],
    counts: dict[str, tuple[int, int]],
) -> str:
    """The model directory's report.md."""
    plant = found[0]
    lines = [
        f"# {model.kind} {model.target}-dynamics model",
        "",
        f"- dataset: `{Path(dataset_dir).resolve()}`, {plant_text(plant)}",
        f"- model: `{MODEL_FILE}`, SHA-256 `{scores['digest']}`",
        f"- seed {scores['seed']}, fitted in {scores['fit_seconds']:.1f} s",
        f"- torque: {_torque_text(dataset_dir, found)}",
    ]
    for split, (episodes, rows) in counts.items():
        lines.append(f"- {split}: {episodes} episodes, {rows:,} ticks")
    if len(found) > 1:
        arms = {rigid_spec(spec) for spec in found}
        same = "the same rigid arm" if len(arms) == 1 else f"{len(arms)} different rigid arms"
        lines.append(
            f"- the episodes mix {len(found)} plants ({same}); the physics uses the first's arm"
        )
    others = plants(dataset_dir, variants=True)
    if others:
        lines.append(
            f"- not learned from: the *_variants splits' episodes, on {len(others)} other plants "
            "(one plant per split, docs/dataset.md)"
        )
    joints = tuple(scores["nmse"])
    robot = plant.robot
    lines += ["", what(model), "", *anchors_table(scores, robot), "", *scores_table(scores), ""]
    lines += [
        "nMSE is the test split's mean squared error over the variance of the measured "
        f"{'torque' if model.target == 'inverse' else 'acceleration'}, per joint; the mean "
        f"is over {span(mean_joints(joints))}, as {joints[-1]}'s torque barely varies (it "
        "turns only the flange: its nMSE measures noise and friction); "
        f"with {joints[-1]} it is {scores['nmse_mean_all']:.4f}. Predicting the training mean "
        "scores "
        f"{scores['mean_predictor_nmse']:.3f}. Calm: the test episodes that ran to their end "
        "without chatter (the dataset's `calm`), what a controller that keeps its limits makes. "
        f"The acceleration is the dataset's `{scores.get('acceleration', ACCELERATION)}`.",
        "",
        f"![predicted against measured, one test episode]({PLOT_FILE})",
        "",
    ]
    return "\n".join(lines)


def _torque_text(dataset_dir: Path, found: list[PlantSpec]) -> str:
    """Which torque the model predicts (or takes, if forward): the motors' whole torque."""
    if motor_torque_column(dataset_dir) == COMMAND:
        return "`u`, the motors' whole torque (a dataset from before `u_motor`, plain torque)"
    if any(plant.interface == "fri" for plant in found):
        return "`u_motor`, the motors' whole torque (behind FRI: `u` and the robot's gravity model)"
    return "`u_motor`, the motors' whole torque (`u`: a plain torque interface)"


def _per_joint(values: np.ndarray, joints: Sequence[str]) -> dict[str, float]:
    return {joint: float(value) for joint, value in zip(joints, values, strict=True)}


def _episode_count(rows: Rows) -> tuple[int, int]:
    return len(set(rows.episode_id)), len(rows)


def no_rows(dataset_dir: Path, split: str) -> str:
    if split == "test":
        return (
            "the dataset has no test split: build it with --split (analytic dataset) "
            "so that some trajectories are held out"
        )
    return f"{str(dataset_dir)!r}: the dataset has no rows in its {split} split"


def _one_line(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return text[:200] if text else type(error).__name__
