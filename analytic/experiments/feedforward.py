"""Does a learned feed-forward make tuned controllers more accurate, against honest baselines?

The question: on paths no step saw, is the PD tuned on top of a model learned from the tuned
PD's own data more accurate than the tuned PD alone, and how far is it from the plant's own model?
Behind KUKA's FRI (the default plant) the PD alone is already PD + gravity compensation (the
robot adds its gravity model), the baseline a real arm runs; the upper anchor is the true-model
feed-forward (models.dynamics.true_model: computed torque with the simulated plant's own arm,
payload and friction), which no learned model can beat.

Per repetition r (seed r everywhere):
1. `pd-r`: tune the PD alone, generic (spiral, random, pyramid at --duration); with --plants K,
   robustly over K plant variants (analytic.tuning.plants);
2. rerun its front on --excitations fourier paths (seeds 200..) and learn a --learner
   inverse-dynamics model from those episodes and the front's own (at most TRAIN_ROWS ticks);
3. `ff-r`: tune the PD again, same seed, on top of that model;
4. on --held-out paths (fourier and random of seeds 1000.., spirals with moved centres) of
   --held-out-duration s, evaluate: `pd` (pd-r's front, PD alone), `pd+true` (its front with the
   true model), `ff` (ff-r's front with its learned model) and `ff+true` (ff-r's front with the
   true model instead: the same gains, the model alone changed).
The default gains run the held-out paths too (PD alone): their torque smoothness is the budget at
which errors are compared, and their episodes are the calm ones on which every model is scored
(nMSE of the motor torque: the learned models, the rigid prior, the true model).

Measures per repetition and condition, over the front's members' held-out means: the error at
the budget (the smallest f_acc among members whose f_t is within the default gains'; the
smoothest member's if none is), the median member's error, the hypervolume (one normalised
space, pooled). Tests: Wilcoxon signed-rank paired by repetition, Holm over the six claims
(three comparisons × error at the budget and hypervolume).

    OUT/runs/{pd,ff}-r/      the tuning runs
    OUT/simulated/NAME/      the rerun data, the calm episodes (kept, reused)
    OUT/held-out/NAME/       the fronts on the held-out paths (kept, reused)
    OUT/models/              rep-r.npz (learned), true.npz
    OUT/results.csv          one row per repetition × condition; points.csv, one per member
    OUT/stats.csv, normalisation.json, feedforward.png, report.md
"""

import json
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gainfarm.analytic.evaluators.batch import EVALUATIONS, batch_jobs, run_batch
from gainfarm.analytic.experiments import dataset_value as data
from gainfarm.analytic.experiments import dataset_value_measures as dv_measures
from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.normalisation import Point, is_penalty
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option, at_least
from gainfarm.analytic.experiments.report import attainment_panel, experiment_setup, markdown_table
from gainfarm.analytic.experiments.runner import Experiment, serving
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.plants import variants
from gainfarm.analytic.tuning.records import RunRecord, results_csv
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.edges.files import write_atomically
from gainfarm.models.dynamics import KINDS, digest, from_bytes, rigid_prior, to_bytes, true_model
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.objectives import NO_EPISODE, objectives
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.trajectories import label

CONDITIONS = ("pd", "pd+true", "ff", "ff+true")
NAMES = {
    "pd": "tuned PD + g-comp",
    "pd+true": "tuned PD + true FF",
    "ff": "PD tuned with learned FF",
    "ff+true": "the same gains + true FF",
}
# The claims tested: (a, b, what it asks).
CLAIMS = (
    ("ff", "pd", "does the learned feed-forward beat PD + gravity compensation?"),
    ("ff+true", "ff", "how far is the learned model from the true one (same gains)?"),
    ("pd+true", "pd", "what does the true model buy the PD front?"),
)
METRICS = (("error_at_budget_mm", False), ("hypervolume", True))  # (measure, higher is better)
LEARNERS = tuple(kind for kind in KINDS if kind != "plant")
EXCITATION_SEED = 200  # the rerun's fourier paths: seeds no run or test uses
FIRST_HELD_OUT_SEED = 1000
MOVED_CENTRES = ((0.5, 0.1, 0.4), (0.6, -0.1, 0.3))  # m: the default is (0.55, 0, 0.35)
TRAIN_ROWS = 60_000  # ticks a model learns from at most (a seeded draw of the pool)
HELD_OUT_DIR = "held-out"
FIGURE = "feedforward.png"


def trained_on(duration: float) -> tuple[TrajectorySpec, ...]:
    return dv_measures.training_trajectories(duration)


def excitations(count: int, duration: float) -> list[TrajectorySpec]:
    return [
        TrajectorySpec(kind="fourier", seed=EXCITATION_SEED + i, duration=duration)
        for i in range(count)
    ]


def held_out_paths(
    count: int,
    duration: float,
    first_seed: int = FIRST_HELD_OUT_SEED,
    centres: Sequence[tuple[float, float, float]] = MOVED_CENTRES,
) -> list[TrajectorySpec]:
    """`count` paths no step saw: fourier, random (seeds `first_seed`..) and spirals moved to
    `centres`, in turn."""
    paths = []
    for index in range(count):
        seed, turn = first_seed + index // 3, index % 3
        if turn == 2:
            centre = centres[(index // 3) % len(centres)]
            paths.append(TrajectorySpec(kind="spiral", duration=duration, center=centre))
        else:
            kind = "fourier" if turn == 0 else "random"
            paths.append(TrajectorySpec(kind=kind, duration=duration, seed=seed))
    return paths


# --- measures (pure) ---------------------------------------------------------------------------


def error_at_budget(points: Sequence[Point], budget: float) -> float:
    """The smallest f_acc among `points` with f_t within `budget`; the smoothest point's f_acc
    if none is (penalties left out); NaN if no point was measured."""
    measured = [p for p in points if not is_penalty(p)]
    if not measured:
        return math.nan
    within = [f_acc for f_acc, f_t in measured if f_t <= budget]
    return min(within) if within else min(measured, key=lambda p: p[1])[0]


def median_error(points: Sequence[Point]) -> float:
    measured = [p[0] for p in points if not is_penalty(p)]
    return statistics.median(measured) if measured else math.nan


@dataclass(frozen=True)
class Claim:
    a: str
    b: str
    question: str
    metric: str
    result: stats.Comparison
    p_holm: float
    higher_is_better: bool

    @property
    def decision(self) -> str:
        adjusted = stats.Comparison(**{**self.result.__dict__, "p_value": self.p_holm})
        return stats.decide(adjusted, NAMES[self.a], NAMES[self.b], self.higher_is_better)


def claims(values: Mapping[tuple[str, str], Sequence[float]]) -> list[Claim]:
    """Every claim on every metric, paired by repetition, Holm-adjusted over all of them.
    `values` maps (condition, metric) to the per-repetition values, in repetition order."""
    found = [
        (a, b, question, metric, better, stats.compare(values[a, metric], values[b, metric], True))
        for a, b, question in CLAIMS
        for metric, better in METRICS
    ]
    adjusted = stats.holm([result.p_value for *_, result in found])
    return [
        Claim(a, b, question, metric, result, p, better)
        for (a, b, question, metric, better, result), p in zip(found, adjusted, strict=True)
    ]


def findings(found: Sequence[Claim], reps: int) -> str:
    """The answer in plain words, from the error at the budget (effect sizes in mm)."""
    on_error = {(c.a, c.b): c for c in found if c.metric == "error_at_budget_mm"}
    lines = []
    for a, b, question in CLAIMS:
        claim = on_error[a, b]
        r = claim.result
        interval = (
            f", 95 % CI of the difference of medians {r.ci_low:+.3f} to {r.ci_high:+.3f} mm"
            if math.isfinite(r.ci_low)
            else ""
        )
        lines.append(
            f"- {question[:1].upper() + question[1:]} Median error at the budget "
            f"{r.median_a:.3f} mm against {r.median_b:.3f} mm{interval}: {claim.decision}."
        )
    if not any(stats.decidable(c.result) for c in found):
        lines.append(
            f"- With {reps} repetition{'s' * (reps != 1)} no paired test here can reach p < "
            f"{stats.ALPHA:g}, let alone after Holm over {len(found)} claims: the data cannot "
            "decide; run at least 8 repetitions (10 recommended)."
        )
    return "\n".join(lines)


# --- running -----------------------------------------------------------------------------------


def scored(
    experiment: Experiment,
    name: str,
    jobs: Mapping[str, EpisodeSpec],
    models: Mapping[str, bytes],
) -> dict[str, Scores | None]:
    """Job id → scores of `jobs`, evaluated in OUT/held-out/NAME through the experiment's
    evaluator serving `models`; a batch finished before (its evaluations.json lists the very
    same specs) is read back, not run again."""
    directory = experiment.out / HELD_OUT_DIR / name
    try:
        records = json.loads((directory / EVALUATIONS).read_text())
        done = {r["job_id"]: r for r in records}
        if all(
            job in done and done[job]["spec"] == s.model_dump(mode="json")
            for job, s in jobs.items()
        ):
            return {
                job: Scores.model_validate(done[job]["scores"]) if done[job]["scores"] else None
                for job in jobs
            }
    except (OSError, ValueError, KeyError, TypeError):
        pass
    directory.mkdir(parents=True, exist_ok=True)
    study = f"{experiment.out.name}-h-{name}"
    with serving(experiment.evaluator(study, directory), models) as evaluator:
        results = {e.job_id: e for e in run_batch(evaluator, dict(jobs), directory)}
    experiment.on_progress(f"{name}: {len(jobs)} held-out episodes")
    return {job: results[job].scores if job in results else None for job in jobs}


def held_out_points(
    experiment: Experiment,
    name: str,
    gains: Sequence[PDGains],
    paths: Sequence[TrajectorySpec],
    base: RunConfig,
    model: bytes | None,
) -> list[Point]:
    """Each controller's mean (f_acc, f_t) over `paths`, with `model` as its feed-forward."""
    wanted = digest(model) if model is not None else None
    jobs = batch_jobs(gains, paths, base.plant, wanted)
    found = scored(experiment, name, jobs, {wanted: model} if model is not None else {})
    ids, per = list(jobs), len(paths)
    points = []
    for index in range(len(gains)):
        each = [found[job] for job in ids[index * per : (index + 1) * per]]
        point = objectives(each)
        if any(s is not None and s.diverged for s in each):
            experiment.penalised.add(point)
        points.append(point)
    return points


def learned_model(
    experiment: Experiment,
    rep: int,
    record: RunRecord,
    base: RunConfig,
    learner: str,
    paths: Sequence[TrajectorySpec],
) -> bytes:
    """The rep's model file (OUT/models/rep-r.npz, kept): learnt from pd-r's front, its own
    episodes and rerun on `paths`."""
    path = experiment.out / "models" / f"rep-{rep}.npz"
    if path.is_file():
        return path.read_bytes()
    front = data.front_logs(record, experiment.out / "runs" / f"pd-{rep}", "front")
    gains = [member.gains for member in record.front]
    rerun = data.simulate(experiment, f"data-{rep}", batch_jobs(gains, paths, base.plant))
    rows = dv_measures.pool_rows(front | {f"data-{rep}/{job}": log for job, log in rerun.items()})
    train, validation = dv_measures.subsample(rows, min(len(rows), TRAIN_ROWS), rep)
    model = dv_measures.fit_model(learner, base.plant, train, validation, rep)
    raw = to_bytes(model)
    write_atomically(path, raw)
    experiment.on_progress(f"rep {rep}: {learner} model learnt from {len(train):,} ticks")
    return raw


def run_config(base: RunConfig, duration: float, rep: int, plants: int) -> RunConfig:
    return base.model_copy(
        update={
            "seed": rep,
            "trajectories": trained_on(duration),
            "plants": variants(base.plant, plants, rep) if plants else (),
        }
    )


def run(
    experiment: Experiment,
    base: RunConfig,
    reps: int,
    learner: str = "linear",
    held_out: int = 6,
    held_out_duration: float = 4.0,
    excitation_count: int = 6,
    plants: int = 0,
) -> list[Claim]:
    """Run the experiment (module docstring) and write its files; return the claims tested."""
    duration = base.trajectories[0].duration
    plant = base.plant
    paths = held_out_paths(held_out, held_out_duration)
    true_raw = to_bytes(true_model(plant))
    (experiment.out / "models").mkdir(parents=True, exist_ok=True)
    write_atomically(experiment.out / "models" / "true.npz", true_raw)
    configs = {rep: run_config(base, duration, rep, plants) for rep in range(reps)}
    pd_runs = experiment.tune_many({f"pd-{rep}": configs[rep] for rep in range(reps)})
    learned = {
        rep: learned_model(
            experiment,
            rep,
            pd_runs[f"pd-{rep}"],
            base,
            learner,
            excitations(excitation_count, duration),
        )
        for rep in range(reps)
    }
    ff_runs = experiment.concurrently(
        {
            rep: (
                lambda rep=rep: experiment.tune(
                    f"ff-{rep}",
                    configs[rep].model_copy(update={"feedforward": digest(learned[rep])}),
                    learned[rep],
                )
            )
            for rep in range(reps)
        }
    )
    calm = data.simulate(experiment, "calm", batch_jobs([DEFAULT_GAINS], paths, plant))
    calm_rows = dv_measures.pool_rows(calm)
    budget = statistics.fmean(dv_measures.objectives(log).f_t for log in calm.values())
    nmse = {
        "rigid prior": dv_measures.score(rigid_prior(plant), calm_rows)["nmse_mean"],
        "true model": dv_measures.score(true_model(plant), calm_rows)["nmse_mean"],
    }
    learned_nmse = [
        dv_measures.score(from_bytes(learned[rep]), calm_rows)["nmse_mean"] for rep in range(reps)
    ]
    points: dict[tuple[int, str], list[Point]] = {}
    for rep in range(reps):
        pd_gains = [m.gains for m in pd_runs[f"pd-{rep}"].front]
        ff_gains = [m.gains for m in ff_runs[rep].front]
        for condition, gains, model in (
            ("pd", pd_gains, None),
            ("pd+true", pd_gains, true_raw),
            ("ff", ff_gains, learned[rep]),
            ("ff+true", ff_gains, true_raw),
        ):
            name = f"{condition.replace('+', '-')}-{rep}"
            points[rep, condition] = held_out_points(experiment, name, gains, paths, base, model)
    space = experiment.normalisation(list(points.values()))
    rows, values = [], {}
    for (rep, condition), found in points.items():
        calm_nmse = {
            "pd": math.nan,
            "ff": learned_nmse[rep],
            "pd+true": nmse["true model"],
            "ff+true": nmse["true model"],
        }
        row = {
            "rep": rep,
            "condition": condition,
            "members": len(found),
            "error_at_budget_mm": 1000 * error_at_budget(found, budget),
            "median_error_mm": 1000 * median_error(found),
            "best_error_mm": 1000
            * min((p[0] for p in found if not is_penalty(p)), default=math.nan),
            "hypervolume": space.hypervolume([p for p in found if p != NO_EPISODE]),
            "budget_f_t": budget,
            "model_calm_nmse": calm_nmse[condition],
        }
        rows.append(row)
        for metric in ("error_at_budget_mm", "median_error_mm", "hypervolume"):
            values.setdefault((condition, metric), []).append(float(row[metric]))  # type: ignore[arg-type]
    found_claims = claims(values)
    experiment.write_results(rows)
    write_atomically(
        experiment.out / "points.csv",
        results_csv(
            [
                {"rep": rep, "condition": condition, "member": index, "f_acc": p[0], "f_t": p[1]}
                for (rep, condition), each in points.items()
                for index, p in enumerate(each)
            ]
        ),
    )
    experiment.write_stats(
        [stats.StatsRow("feedforward", f"{c.a} vs {c.b}", c.metric, c.result) for c in found_claims]
    )
    experiment.write_normalisation({"held-out": space})
    figure(experiment.out / FIGURE, points, values, reps)
    report(
        experiment,
        base,
        reps,
        learner=learner,
        paths=paths,
        excitation_count=excitation_count,
        plants=plants,
        budget=budget,
        values=values,
        nmse=nmse,
        learned_nmse=learned_nmse,
        found=found_claims,
        space=space,
    )
    return found_claims


# --- the report and the figure -----------------------------------------------------------------


def _path_text(path: TrajectorySpec) -> str:
    return label(path)  # the kind's own rule: no branch on a kind's name here


def report(
    experiment: Experiment,
    base: RunConfig,
    reps: int,
    *,
    learner: str,
    paths: Sequence[TrajectorySpec],
    excitation_count: int,
    plants: int,
    budget: float,
    values: Mapping[tuple[str, str], Sequence[float]],
    nmse: Mapping[str, float],
    learned_nmse: Sequence[float],
    found: Sequence[Claim],
    space: Any,
) -> None:
    duration = base.trajectories[0].duration
    setup = experiment_setup(
        run_config(base, duration, 0, plants), reps, {"held-out": (space.ideal, space.nadir)}
    )

    def cell(condition: str, metric: str, form: str) -> str:
        each = values[condition, metric]
        return format(statistics.median(each), form) if each else "–"

    table = markdown_table(
        ["condition", "error at budget, mm", "median member, mm", "hypervolume"],
        (
            [
                NAMES[c],
                cell(c, "error_at_budget_mm", ".3f"),
                cell(c, "median_error_mm", ".3f"),
                cell(c, "hypervolume", ".3f"),
            ]
            for c in CONDITIONS
        ),
    )
    claims_table = markdown_table(
        ["claim", "metric", "median a", "median b", "p", "p (Holm)", "A12", "95 % CI of a − b"],
        (
            [
                f"{NAMES[c.a]} vs {NAMES[c.b]}",
                c.metric,
                f"{c.result.median_a:.4g}",
                f"{c.result.median_b:.4g}",
                f"{c.result.p_value:.3g}",
                f"{c.p_holm:.3g}",
                f"{c.result.a12:.2f}",
                f"{c.result.ci_low:+.4g} to {c.result.ci_high:+.4g}",
            ]
            for c in found
        ),
        text_columns=2,
    )
    models = markdown_table(
        ["model", "calm-episode nMSE (mean A1-A6)"],
        [
            [f"learned ({learner}), median of {reps}", f"{statistics.median(learned_nmse):.4f}"],
            ["rigid prior (nominal arm, no friction)", f"{nmse['rigid prior']:.4f}"],
            ["true model (the plant's own)", f"{nmse['true model']:.4f}"],
        ],
    )
    lines = [
        "# The learned feed-forward against PD + gravity compensation and the true model",
        "",
        "**Question.** On paths no step saw, does the PD tuned on top of a model learned from "
        "the tuned PD's own data track better than the tuned PD alone (behind FRI: PD + "
        "gravity compensation), and how far is it from the plant's own model?",
        "",
        "**Design.**",
        "",
        *[f"- {line}" for line in setup],
        f"- per repetition: the PD tuned alone (`pd-r`), a {learner} model learnt from its "
        f"front's episodes and the front rerun on {excitation_count} fourier excitations "
        f"(seeds {EXCITATION_SEED}..), the PD tuned again on top of it (`ff-r`)"
        + (f"; both robust over {plants} plant variants" if plants else ""),
        f"- held-out: {', '.join(_path_text(p) for p in paths)}, "
        f"{paths[0].duration:g} s each (the runs tuned on {duration:g} s paths)",
        "- baselines: the tuned PD alone (PD + g-comp behind FRI); anchor: the true-model "
        "feed-forward (the plant's own arm, payload and friction), on either front's gains",
        f"- measures over each front's members' held-out means: the error at the budget (the "
        f"smallest f_acc with f_t within the default gains' held-out f_t, {budget:.3g} (N·m)²; "
        "the smoothest member's if none is), the median member's error, the hypervolume",
        f"- test: Wilcoxon signed-rank paired by repetition, Holm over the {len(found)} claims "
        "below (alpha 0.05)",
        "",
        "## Medians over repetitions",
        "",
        *table,
        "",
        "## Findings",
        "",
        findings(found, reps),
        "",
        "## Claims",
        "",
        *claims_table,
        "",
        "## The models on calm episodes",
        "",
        "The default gains' episodes on the held-out paths (PD alone): how well each model "
        "predicts the motors' torque where no controller chatters.",
        "",
        *models,
        "",
        "The true model's feed-forward leaves what no model of the arm can say: the springs' "
        "deflection and the command's tick of delay (bench/true_feedforward.py measures the "
        "floor with them compensated; docs/experiments.md).",
        "",
        f"![{FIGURE}]({FIGURE})",
        "",
    ]
    write_atomically(experiment.out / "report.md", "\n".join(lines).encode())


def figure(
    path: Path,
    points: Mapping[tuple[int, str], Sequence[Point]],
    values: Mapping[tuple[str, str], Sequence[float]],
    reps: int,
) -> None:
    """Left: each condition's median attainment surface on the held-out paths; right: the
    error at the budget per repetition."""
    canvas = new_figure((10.0, 4.2))
    left, right = canvas.subplots(1, 2)
    attainment_panel(
        left,
        {NAMES[c]: [points[rep, c] for rep in range(reps)] for c in CONDITIONS},
        "held-out paths",
    )
    for index, condition in enumerate(CONDITIONS):
        each = [v for v in values[condition, "error_at_budget_mm"] if math.isfinite(v)]
        right.scatter([index] * len(each), each, s=16, alpha=0.7)
        if each:
            right.hlines(statistics.median(each), index - 0.3, index + 0.3, color="black")
    right.set_xticks(range(len(CONDITIONS)))
    right.set_xticklabels([NAMES[c] for c in CONDITIONS], rotation=20, ha="right", fontsize=7)
    right.set(ylabel="error at the budget, mm", title="per repetition")
    right.set_yscale("log")
    save_png(canvas, path)


# --- the declaration -----------------------------------------------------------------------------


def learner_choice(text: str) -> str:
    if text not in LEARNERS:
        raise ValueError(f"{text!r} is not one of {', '.join(LEARNERS)}")
    return text


def positive_duration(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"expected seconds, got {text!r}") from None
    if not 0.1 <= value <= 120:
        raise ValueError(f"{value:g} s is not within 0.1-120 s")
    return value


def every_trajectory(base: RunConfig, options: Mapping[str, Any]) -> list[TrajectorySpec]:
    """Every path the experiment's episodes follow: the training kinds, the excitations and the
    held-out paths."""
    duration = base.trajectories[0].duration
    return [
        *trained_on(duration),
        *excitations(options.get("excitation_count", 6), duration),
        *held_out_paths(options.get("held_out", 6), options.get("held_out_duration", 4.0)),
    ]


EXPERIMENT = ExperimentSpec(
    name="feedforward",
    robots=("iiwa14",),  # one arm's by design, as yet
    only_on="its learned models and the true-model anchor are the iiwa 14's (analytic/data)",
    summary="the learned feed-forward against PD + gravity compensation and the true model's",
    run=run,
    options=(
        Option(
            "--learner",
            "learner",
            "the model learnt: " + ", ".join(LEARNERS),
            "linear",
            learner_choice,
            "KIND",
        ),
        Option(
            "--held-out",
            "held_out",
            "held-out paths (fourier, random, moved spirals)",
            "6",
            at_least(1),
            "N",
        ),
        Option(
            "--held-out-duration",
            "held_out_duration",
            "the held-out paths' duration, s",
            "4",
            positive_duration,
            "S",
        ),
        Option(
            "--excitations",
            "excitation_count",
            "fourier paths the front is rerun on for the model's data",
            "6",
            at_least(0),
            "N",
        ),
        Option(
            "--plants",
            "plants",
            "tune robustly over N plant variants (0: the nominal)",
            "0",
            at_least(0),
            "N",
        ),
    ),
    duration=3.0,
    trajectories=every_trajectory,
    trajectory_option="--duration, --held-out-duration",
)
