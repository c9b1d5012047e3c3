"""The dataset-value experiment's pure parts (analytic.experiments.dataset_value): its conditions,
the trajectories and controllers its pools hold, the rows drawn from their logs, the models
trained on them and their scores, the paired comparisons and the findings they support; functions
of plain data, which run nothing.
"""

import hashlib
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from gainfarm.analytic.data.dataset import is_calm, joints_of, tick_columns
from gainfarm.analytic.data.learning import Rows, identify, mean_joints, train_network
from gainfarm.analytic.experiments.runner import ALL_KINDS
from gainfarm.analytic.experiments.statistics import holm
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.models.dynamics import DynamicsModel, rigid_prior
from gainfarm.schemas.episode import Scores
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import score as score_episode
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import TrajectoryKind, TrajectorySpec

# The conditions: where a pool's episodes come from. The first five are tuned selections.
TUNED = ("specific-front", "specific-knee", "specific-rerun", "generic-front", "generic-knee")
REFERENCES = ("default", "random")
CONDITIONS = TUNED + REFERENCES
MODELS = ("linear", "mlp", "residual")  # trained on each condition's rows
REFERENCE_MODEL = "rigid"  # the physics prior: trained on nothing, scored once
FLOOR_MODEL = "plant"  # the true model: the plant's own dynamics, scored once
BASELINES = (REFERENCE_MODEL, FLOOR_MODEL)
MEASURES = {"nmse_mean": "nMSE", "rmse_mean": "RMSE (N·m)"}  # score column → report's name
RANDOM_CONTROLLERS = 3  # random gain sets per repetition, each on the three trajectories
TEST_SEED = 999  # the test pool's random controllers: fixed, the same in every repetition
TEST_RANDOM_CONTROLLERS = 2
# Draws from which the test's random controllers are taken: the first TEST_RANDOM_CONTROLLERS
# whose torque steps (f_t) stay within CHATTER_FACTOR of the default gains' on every test
# trajectory. Seed 999's first draw (Kd 71 on A2) feeds the elastic joints' spring mode: f_t
# 5,800-44,000 (N·m)² against the default's 0.1-0.2, a torque variance 100 times the others'
# that alone set the pooled nMSE (the rigid prior's 64-170 on it, 0.4-1.1 elsewhere). A test
# of the arm's dynamics should not be a test of one chattering controller's spring mode.
TEST_DRAWS = 12
CHATTER_FACTOR = 100.0
FIRST_TEST_SEED = 1000  # held-out trajectories' seeds: no run's trajectory has one
DEFAULT_TEST_TRAJECTORIES = 6
DEFAULT_DURATION = 3.0  # s: the pyramid needs 2.8 s
VALIDATION_FRACTION = 0.2  # of each condition's N_ticks rows: the network's epoch choice
ALPHA = 0.05
MIN_REPS = 3  # fewer: no test, "cannot decide"


# --- trajectories and controllers ------------------------------------------------------------


def training_trajectories(duration: float) -> tuple[TrajectorySpec, ...]:
    """The three Cartesian kinds the runs tune on, at `duration`."""
    return tuple(TrajectorySpec(kind=kind, duration=duration) for kind in ALL_KINDS)


def test_trajectories(duration: float, count: int) -> list[TrajectorySpec]:
    """`count` held-out trajectories: fourier seeds 1000.. and random-kind seeds 1000..,
    alternately. A fourier excitation is a motion no Cartesian run saw at all; the random kind
    with a seed no run uses is the same family as a training path, elsewhere in the workspace."""
    kinds = (TrajectoryKind.fourier, TrajectoryKind.random)
    return [
        TrajectorySpec(kind=kinds[index % 2], duration=duration, seed=FIRST_TEST_SEED + index // 2)
        for index in range(count)
    ]


def smooth_controllers(
    default_f_t: Sequence[float], candidates_f_t: Sequence[Sequence[float]], count: int
) -> list[int]:
    """Indices of the first `count` candidates whose f_t on every trajectory is at most
    CHATTER_FACTOR times the default gains' there (the lists are per trajectory, in one order).
    ValueError if fewer pass."""
    chosen = [
        index
        for index, values in enumerate(candidates_f_t)
        if all(
            math.isfinite(value) and value <= CHATTER_FACTOR * default
            for value, default in zip(values, default_f_t, strict=True)
        )
    ][:count]
    if len(chosen) < count:
        raise ValueError(
            f"only {len(chosen)} of {len(candidates_f_t)} random test controllers (seed "
            f"{TEST_SEED}) run without chattering; the test pool needs {count}"
        )
    return chosen


def random_gains(seed: int, count: int) -> list[PDGains]:
    """`count` controllers drawn uniformly from the search space (log-uniform gains), seeded:
    what NSGA-II's first generation is made of, before any selection."""
    space = SearchSpace()
    draws = np.random.default_rng(seed).uniform(space.lower, space.upper, (count, space.lower.size))
    return [space.gains(row) for row in draws]


# --- rows ------------------------------------------------------------------------------------


def episode_rows(path: Path, episode_id: str) -> Rows:
    """One episode's ticks with a finite acceleration, by the dataset's own rule
    (analytic.data.dataset.tick_columns: q̈ of the Savitzky-Golay fit, `qdd_sg`; any
    non-finite row dropped), flagged calm or not as the dataset flags it. `u` is the motors'
    whole torque, the dataset's u_motor: what the models learn (analytic.learning.read_split)."""
    log = read_episode(path)
    columns = tick_columns(episode_id, log)
    joints = joints_of(log)
    signals = {
        signal: np.column_stack([columns[f"{column}_{joint}"] for joint in joints])
        for signal, column in (("q", "q"), ("qd", "qd"), ("qdd", "qdd_sg"), ("u", "u_motor"))
    }
    finite = np.isfinite(np.hstack(list(signals.values()))).all(axis=1)
    scores = score_episode(log)
    calm = is_calm(float(scores.chatter), bool(scores.diverged))
    return Rows(
        episode_id=columns["episode_id"][finite].astype(str),
        t=np.asarray(columns["t"], dtype=float)[finite],
        calm=np.full(int(finite.sum()), calm),
        **{signal: values[finite].astype(float) for signal, values in signals.items()},
        joints=joints,
    )


def objectives(path: Path) -> Scores:
    """An episode's objectives, scored from its log (as every evaluator scores it)."""
    return score_episode(read_episode(path))


def pool_rows(episodes: Mapping[str, Path]) -> Rows:
    """Every finite row of a pool's calm episodes (episode id → log), in id order: what
    `analytic dataset` keeps unless --include-rough."""
    rows = Rows.concatenate([episode_rows(episodes[key], key) for key in sorted(episodes)])
    return rows.take(rows.calm)


def subsample(rows: Rows, count: int, seed: int) -> tuple[Rows, Rows]:
    """(train, validation): `count` rows drawn without replacement with `seed`, the last
    VALIDATION_FRACTION of the draw held back for the network's epoch choice. Every condition
    gets the same `count`, so no pool wins by being larger; a larger pool only spreads the same
    number of ticks over more motions, which is what "richer" should mean."""
    if count > len(rows):
        raise ValueError(f"--ticks: {count} rows asked for, but a pool holds only {len(rows)}")
    drawn = np.random.default_rng(seed).permutation(len(rows))[:count]
    held = round(VALIDATION_FRACTION * count)
    return rows.take(np.sort(drawn[: count - held])), rows.take(np.sort(drawn[count - held :]))


def rows_digest(rows: Rows) -> str:
    """A short SHA-256 of the rows' numbers and ids: equal digests, the very same test data."""
    hasher = hashlib.sha256()
    for name in ("q", "qd", "qdd", "u", "t"):
        hasher.update(np.ascontiguousarray(getattr(rows, name), dtype=np.float64).tobytes())
    hasher.update("\n".join(rows.episode_id.tolist()).encode())
    return hasher.hexdigest()[:16]


# --- models ----------------------------------------------------------------------------------


def fit_model(
    kind: str, plant: PlantSpec, train: Rows, validation: Rows, seed: int
) -> DynamicsModel:
    """An inverse-dynamics model of `kind` from in-memory rows, built as analytic.learning.fit
    builds it from a dataset directory (the linear model uses the train rows only, as there)."""
    prior = rigid_prior(plant, "inverse")
    if kind == REFERENCE_MODEL:
        return prior
    about: dict[str, Any] = {"train_rows": len(train), "seed": seed}
    if kind == "linear":
        parameters, rank, _ = identify(prior.spec, train)
        return DynamicsModel(
            kind="linear",
            target="inverse",
            spec=prior.spec,
            parameters=parameters,
            about=about | {"identified_rank": rank},
        )
    if kind not in ("mlp", "residual"):
        raise ValueError(f"unknown model {kind!r}")
    subtract = prior if kind == "residual" else None
    network, notes = train_network(train, validation, "inverse", subtract, seed)
    about |= {"validation_rows": len(validation)} | notes
    return DynamicsModel(kind=kind, target="inverse", spec=prior.spec, network=network, about=about)


def score(model: DynamicsModel, test: Rows) -> dict[str, float]:
    """nMSE (MSE over the variance of the test torque) and RMSE (N·m) per joint, and the mean
    of each over A1..A6 (analytic.learning's convention: the flange's joint, A7, barely varies;
    any arm's joints but its last)."""
    error = model.inverse(test.q, test.qd, test.qdd) - test.u
    mse = (error**2).mean(axis=0)
    nmse = mse / test.u.var(axis=0)
    joints = test.joints
    mean = [joints.index(j) for j in mean_joints(joints)]
    row = {
        "nmse_mean": float(np.mean(nmse[mean])),
        "rmse_mean": float(np.mean(np.sqrt(mse[mean]))),
    }
    row |= {f"nmse_{joint}": float(value) for joint, value in zip(joints, nmse, strict=True)}
    row |= {
        f"rmse_{joint}": float(value) for joint, value in zip(joints, np.sqrt(mse), strict=True)
    }
    return row


# --- statistics --------------------------------------------------------------------------------


@dataclass(frozen=True)
class PairedTTest:
    """`condition` against `against` for `model`, paired by repetition (a t-test: see `paired`).
    mean_difference is condition's nMSE minus against's: negative means the condition's data
    taught more."""

    model: str
    condition: str
    against: str
    mean_difference: float
    t: float
    p: float
    p_holm: float
    d_z: float
    n: int

    @property
    def decided(self) -> bool:
        return math.isfinite(self.p_holm) and self.p_holm < ALPHA

    @property
    def finding(self) -> str:
        """ "better", "worse" (lower, higher nMSE, significantly after Holm) or "cannot decide"."""
        if not self.decided:
            return "cannot decide"
        return "better" if self.mean_difference < 0 else "worse"

    def row(self) -> dict[str, object]:
        return {
            "model": self.model,
            "condition": self.condition,
            "against": self.against,
            "mean_difference": self.mean_difference,
            "t": self.t,
            "p": self.p,
            "p_holm": self.p_holm,
            "d_z": self.d_z,
            "n": self.n,
        }


def paired(
    model: str, condition: str, against: str, values: Sequence[float], others: Sequence[float]
) -> PairedTTest:
    """A paired t-test (scipy's ttest_rel) and Cohen's d_z (mean difference over the standard
    deviation of the differences). Fewer than MIN_REPS pairs: no test (NaN p, "cannot decide").
    Identical differences, where the t statistic is undefined, are decided by hand: all zero is
    no difference (p 1), all equal and non-zero a difference no repetition contradicts (p 0)."""
    differences = np.asarray(values, dtype=float) - np.asarray(others, dtype=float)
    n = len(differences)
    mean = float(differences.mean()) if n else math.nan
    if n < MIN_REPS:
        return PairedTTest(
            model, condition, against, mean, math.nan, math.nan, math.nan, math.nan, n
        )
    spread = float(differences.std(ddof=1))
    if spread <= 1e-12 * max(1.0, abs(mean)):
        if abs(mean) <= 1e-15:
            return PairedTTest(model, condition, against, 0.0, 0.0, 1.0, 1.0, 0.0, n)
        infinite = math.copysign(math.inf, mean)
        return PairedTTest(model, condition, against, mean, infinite, 0.0, 0.0, infinite, n)
    result = stats.ttest_rel(values, others)
    p = float(result.pvalue)
    return PairedTTest(
        model, condition, against, mean, float(result.statistic), p, p, mean / spread, n
    )


def compare(
    nmse: Mapping[tuple[str, str], Sequence[float]], models: Sequence[str] = MODELS
) -> list[PairedTTest]:
    """Each tuned condition against each reference, per model, Holm-adjusted as one family:
    the report shows every model's, so every one is a claim.

    `nmse` maps (model, condition) to the nmse_mean of repetitions 0..n-1, in that order."""
    family = [
        paired(model, condition, against, nmse[(model, condition)], nmse[(model, against)])
        for model in models
        for condition in TUNED
        for against in REFERENCES
    ]
    adjusted = holm([comparison.p for comparison in family])
    return [PairedTTest(**(c.row() | {"p_holm": p})) for c, p in zip(family, adjusted, strict=True)]


def mean_nmse(nmse: Mapping[tuple[str, str], Sequence[float]], model: str, condition: str) -> float:
    return statistics.fmean(nmse[(model, condition)])


def best_model(
    nmse: Mapping[tuple[str, str], Sequence[float]], models: Sequence[str] = MODELS
) -> str:
    """The model with the lowest median nMSE over every condition and repetition: a median,
    since one pool of chattering episodes can make a network's nMSE fifty times its usual."""
    return min(
        models, key=lambda model: statistics.median(v for c in CONDITIONS for v in nmse[(model, c)])
    )


@dataclass(frozen=True)
class Conclusion:
    model: str
    against_default: dict[str, str]  # tuned condition → "better" / "worse" / "cannot decide"
    best_selection: str
    runner_up: str
    selection_test: PairedTTest  # best against runner-up (one test: no adjustment)
    text: str


def findings(
    nmse: Mapping[tuple[str, str], Sequence[float]],
    comparisons: Sequence[PairedTTest],
    models: Sequence[str] = MODELS,
    rmse: Mapping[tuple[str, str], Sequence[float]] | None = None,
    floor: Mapping[str, float] | None = None,
) -> Conclusion:
    """The answer in plain words, for the best model: does each tuned selection's data teach
    significantly more than the default gains' (Holm-adjusted, alpha 0.05)? And which selection
    teaches the most, and is it significantly ahead of the runner-up? With `rmse` (as `nmse`, in
    N·m) and `floor` (the true model's scores), each figure also in N·m and beside the floor."""
    model = best_model(nmse, models)
    reps = len(nmse[(model, "default")])
    mine = {(c.condition, c.against): c for c in comparisons if c.model == model}
    outcomes = {condition: mine[(condition, "default")].finding for condition in TUNED}
    ranked = sorted(TUNED, key=lambda c: mean_nmse(nmse, model, c))
    best, second = ranked[0], ranked[1]
    head = paired(model, best, second, nmse[(model, best)], nmse[(model, second)])
    better = [c for c in TUNED if outcomes[c] == "better"]
    worse = [c for c in TUNED if outcomes[c] == "worse"]
    default = mean_nmse(nmse, model, "default")

    def newton_metres(condition: str) -> str:
        if rmse is None:
            return ""
        return f", RMSE {statistics.fmean(rmse[(model, condition)]):.3f} N·m"

    lines = [
        f"With the best model here ({model}, the lowest median nMSE over all conditions), "
        f"the default gains' data give a mean test nMSE of {default:.4f}"
        f"{newton_metres('default')}"
        + (
            f"; the true model scores {floor['nmse_mean']:.4f} ({floor['rmse_mean']:.3f} N·m) "
            "on the same rows, the floor."
            if floor is not None
            else "."
        )
    ]
    if reps < MIN_REPS:
        lines.append(
            f"With {reps} repetition{'s' * (reps != 1)} the data cannot decide the paper's claim "
            f"(a paired test needs at least {MIN_REPS}): run more repetitions."
        )
    elif len(better) == len(TUNED):
        lines.append(
            "Every tuned selection's data teach significantly more (lower nMSE, paired t-test, "
            f"Holm-adjusted p < {ALPHA}) than the default gains' at equal ticks: the paper's "
            "claim of a richer database holds here."
        )
    elif better:
        lines.append(
            f"The data of {listed(better)} teach significantly more than the default gains' "
            f"(Holm-adjusted p < {ALPHA}); for {listed([c for c in TUNED if c not in better])} "
            "the data "
            + ("cannot decide" if not worse else f"say otherwise ({listed(worse)}: worse)")
            + ": the paper's claim holds only for some selections."
        )
    elif worse:
        lines.append(
            f"No tuned selection's data teach significantly more than the default gains'; "
            f"{listed(worse)} teach{'es' * (len(worse) == 1)} significantly less "
            f"(Holm-adjusted p < {ALPHA}): the paper's claim is contradicted here."
        )
    else:
        lines.append(
            "No tuned selection's data differ significantly from the default gains' "
            f"(every Holm-adjusted p >= {ALPHA}): the data cannot decide the paper's claim; "
            "it is not shown."
        )
    if reps >= MIN_REPS:
        beat_random = [c for c in TUNED if mine[(c, "random")].finding == "better"]
        lines.append(
            "Against random search-space gains' data, "
            + (
                f"{listed(beat_random)} teach{'es' * (len(beat_random) == 1)} significantly more."
                if beat_random
                else "no tuned selection teaches significantly more."
            )
        )
    if math.isfinite(head.p):
        ahead = (
            f"significantly (paired t-test p = {head.p:.3g}, d_z = {head.d_z:.2f})"
            if head.p < ALPHA
            else f"but not significantly (p = {head.p:.3g}): the data cannot separate the two"
        )
    else:
        ahead = "(too few repetitions to test the difference)"
    lines.append(
        f"The most useful selection is {best} (mean nMSE {mean_nmse(nmse, model, best):.4f}"
        f"{newton_metres(best)}), ahead of {second} ({mean_nmse(nmse, model, second):.4f}"
        f"{newton_metres(second)}) {ahead}."
    )
    return Conclusion(model, outcomes, best, second, head, " ".join(lines))


def listed(names: Sequence[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
