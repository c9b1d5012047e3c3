"""Is a tuned controller's data worth more for learning the arm's dynamics? The experiment.

The paper claims tuned controllers make a "richer database" for learning the robot's dynamics.
This experiment tests it at equal amounts of data: per repetition r (seed r everywhere) it tunes
three specific controllers (one per Cartesian trajectory kind) and a generic one (all three),
gathers a pool of episodes per condition (which controllers, on which trajectories), draws the
same number of ticks from every pool, trains the same models on each and scores them all on one
held-out test pool, which no condition's controllers ran. Then, paired by repetition, a t-test
and an effect size per tuned condition against the default gains and against random ones, all
Holm-adjusted as one family. Two baselines score the same test pool untrained: the rigid prior
(the nominal arm a learned model starts from) and the true model (the simulated plant's own
dynamics: its error is what the logged columns' noise leaves, the floor a learned model is
measured against). Every pool is clean by the dataset's rule (analytic.data.dataset): only calm
episodes, with the Savitzky-Golay acceleration `qdd_sg`.

    OUT/runs/NAME/             the tuning runs (Experiment.tune: kept, resumed, or started)
    OUT/simulated/NAME/        batches of extra episodes (reruns, default, random, the test
                               pool): kept when finished, so a second invocation reuses them
    OUT/results.csv            one row per rep × condition × model (and the two baselines)
    OUT/comparisons.csv        one row per paired comparison
    OUT/dataset-value.png      nMSE per condition, one panel per model
    OUT/report.md              setup, table, comparisons, findings, limitations

The pure parts (pools, subsampling, scoring, statistics, the findings) are functions of plain
data (analytic.experiments.dataset_value_measures); `run` is the only one that runs anything.
"""

import functools
import json
import math
import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from gainfarm.analytic.data.dataset import select
from gainfarm.analytic.data.learning import MEAN_JOINTS, Rows
from gainfarm.analytic.evaluators.batch import EVALUATIONS, batch_jobs, run_batch
from gainfarm.analytic.experiments.dataset_value_measures import (
    BASELINES,
    CHATTER_FACTOR,
    CONDITIONS,
    DEFAULT_DURATION,
    DEFAULT_TEST_TRAJECTORIES,
    FIRST_TEST_SEED,
    FLOOR_MODEL,
    MEASURES,
    MODELS,
    RANDOM_CONTROLLERS,
    REFERENCE_MODEL,
    TEST_DRAWS,
    TEST_RANDOM_CONTROLLERS,
    TEST_SEED,
    VALIDATION_FRACTION,
    Conclusion,
    PairedTTest,
    compare,
    findings,
    fit_model,
    listed,
    objectives,
    pool_rows,
    random_gains,
    rows_digest,
    score,
    smooth_controllers,
    subsample,
    test_trajectories,
    training_trajectories,
)
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option, at_least
from gainfarm.analytic.experiments.report import markdown_table
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import RunRecord, results_csv
from gainfarm.analytic.view.figures import new_figure, save_png
from gainfarm.analytic.view.reports import plant_text
from gainfarm.edges.files import write_atomically
from gainfarm.models.dynamics import rigid_prior, true_model
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec

SIMULATED = "simulated"
FIGURE = "dataset-value.png"


# --- running -----------------------------------------------------------------------------------


def simulate(experiment: Experiment, name: str, jobs: Mapping[str, EpisodeSpec]) -> dict[str, Path]:
    """Job id → log of `jobs`, simulated through the experiment's evaluator into
    OUT/simulated/NAME; a batch finished before (its evaluations.json, written last, lists the
    very same specs and every log is there) is reused, not simulated again. ValueError if an
    episode did not run: a pool would silently be short of it."""
    directory = experiment.out / SIMULATED / name
    done = _finished_batch(directory, jobs)
    if done is not None:
        return done
    directory.mkdir(parents=True, exist_ok=True)
    with experiment.evaluator(f"{experiment.out.name}-d-{name}", directory) as evaluator:
        results = {e.job_id: e for e in run_batch(evaluator, dict(jobs), directory)}
    missing = [job for job in jobs if job not in results or results[job].log is None]
    if missing:
        result = results.get(missing[0])
        why = f"{result.status.value}: {result.reason}" if result else "lost"
        raise ValueError(f"{name}: episode {missing[0]} did not run ({why})")
    experiment.on_progress(f"{name}: {len(jobs)} episodes simulated")
    return {job: results[job].log for job in jobs}  # type: ignore[misc]  # checked above


def _finished_batch(directory: Path, jobs: Mapping[str, EpisodeSpec]) -> dict[str, Path] | None:
    try:
        records = json.loads((directory / EVALUATIONS).read_text())
    except (OSError, ValueError):
        return None
    found = {record["job_id"]: record for record in records if record.get("episode")}
    if set(found) != set(jobs):
        return None
    logs = {}
    for job, spec in jobs.items():
        path = directory / found[job]["episode"]
        if found[job]["spec"] != spec.model_dump(mode="json") or not path.is_file():
            return None
        logs[job] = path
    return logs


def front_logs(record: RunRecord, directory: Path, selection: str) -> dict[str, Path]:
    """Episode id → log of the selected members' tuning episodes (front.json's index)."""
    members = select(record, selection)  # type: ignore[arg-type]  # "front" or "knee"
    found = {
        f"{directory.name}/{Path(log).stem}": directory / log
        for member in members
        for log in member.logs
        if (directory / log).is_file()
    }
    if not found:
        raise ValueError(f"{directory}: the {selection} has no episode log (keep the front's)")
    return found


def batch_logs(
    experiment: Experiment,
    name: str,
    gains: Sequence[PDGains],
    trajectories: Sequence[TrajectorySpec],
    plant: PlantSpec,
) -> dict[str, Path]:
    """Episode id → log of every controller on every trajectory, simulated (or reused)."""
    logs = simulate(experiment, name, batch_jobs(gains, trajectories, plant))
    return {f"{name}/{job}": path for job, path in logs.items()}


def tuning_plan(base: RunConfig, reps: int) -> dict[str, RunConfig]:
    """Every tuning run of the experiment: per repetition, one specific run per training
    trajectory and one generic run on all three, seeded by the repetition."""
    trajectories = training_trajectories(base.trajectories[0].duration)
    plan: dict[str, RunConfig] = {}
    for rep in range(reps):
        for trajectory in trajectories:
            plan[f"specific-{trajectory.kind}-rep{rep}"] = base.model_copy(
                update={"trajectories": (trajectory,), "seed": rep}
            )
        plan[f"generic-rep{rep}"] = base.model_copy(
            update={"trajectories": trajectories, "seed": rep}
        )
    return plan


def all_pools(
    experiment: Experiment, base: RunConfig, reps: int
) -> list[dict[str, dict[str, Path]]]:
    """Each repetition's pools (condition → its episodes, id → log): every tuning run of every
    repetition at once, then every batch of episodes they call for at once (as wide as the
    farm; `Experiment.parallel` bounds it), each reused if done before."""
    trajectories = training_trajectories(base.trajectories[0].duration)
    plant = base.plant
    records = experiment.tune_many(tuning_plan(base, reps))

    def batch(name: str, gains: Sequence[PDGains], on: Sequence[TrajectorySpec]) -> Callable:
        return functools.partial(batch_logs, experiment, name, gains, on, plant)

    # The default gains' episodes are the same in every repetition (a simulation is
    # deterministic): simulated once; each repetition draws its own subsample of them.
    batches = {"default": batch("default", [DEFAULT_GAINS], trajectories)}
    for rep in range(reps):
        for trajectory in trajectories:  # each specific knee once more on the other two
            name = f"specific-{trajectory.kind}-rep{rep}"
            knee = select(records[name], "knee")[0].gains
            others = [other for other in trajectories if other != trajectory]
            batches[f"{name}-knee-rerun"] = batch(f"{name}-knee-rerun", [knee], others)
        random = random_gains(rep, RANDOM_CONTROLLERS)
        batches[f"random-rep{rep}"] = batch(f"random-rep{rep}", random, trajectories)
    logs = experiment.concurrently(batches)
    return [pools_of_rep(experiment.out, records, logs, rep, trajectories) for rep in range(reps)]


def pools_of_rep(
    out: Path,
    records: Mapping[str, RunRecord],
    logs: Mapping[str, dict[str, Path]],
    rep: int,
    trajectories: Sequence[TrajectorySpec],
) -> dict[str, dict[str, Path]]:
    """Condition → its episodes (id → log) for repetition `rep`, from the experiment's tuning
    runs (`records`, by name) and batches of episodes (`logs`, by name)."""
    pools: dict[str, dict[str, Path]] = {condition: {} for condition in CONDITIONS}
    for trajectory in trajectories:
        name = f"specific-{trajectory.kind}-rep{rep}"
        directory = out / "runs" / name
        pools["specific-front"] |= front_logs(records[name], directory, "front")
        own = front_logs(records[name], directory, "knee")
        pools["specific-knee"] |= own
        pools["specific-rerun"] |= own | logs[f"{name}-knee-rerun"]
    name = f"generic-rep{rep}"
    pools["generic-front"] = front_logs(records[name], out / "runs" / name, "front")
    pools["generic-knee"] = front_logs(records[name], out / "runs" / name, "knee")
    pools["default"] = logs["default"]
    pools["random"] = logs[f"random-rep{rep}"]
    return pools


def test_pool(
    experiment: Experiment, duration: float, count: int, plant: PlantSpec
) -> tuple[Rows, list[int]]:
    """The test rows: the default gains and TEST_RANDOM_CONTROLLERS smooth random controllers
    (`smooth_controllers` among TEST_DRAWS draws of seed TEST_SEED) on `count` held-out
    trajectories; and the indices of the draws taken."""
    trajectories = test_trajectories(duration, count)
    candidates = random_gains(TEST_SEED, TEST_DRAWS)
    jobs = batch_jobs([DEFAULT_GAINS, *candidates], trajectories, plant)
    logs = simulate(experiment, "test", jobs)
    ids = list(jobs)  # candidate by candidate, trajectory by trajectory (batch_jobs' order)
    f_t = [objectives(logs[job]).f_t for job in ids]
    per = len(trajectories)
    table = [f_t[index * per : (index + 1) * per] for index in range(1 + len(candidates))]
    accepted = smooth_controllers(table[0], table[1:], TEST_RANDOM_CONTROLLERS)
    taken = {0, *(index + 1 for index in accepted)}
    kept = {f"test/{job}": logs[job] for number, job in enumerate(ids) if number // per in taken}
    return pool_rows(kept), accepted


def smallest_pool(duration: float) -> int:
    """Rows of the smallest pool possible before anything runs: three whole episodes (a knee on
    its own trajectory, the default gains on the three); a diverged or rough episode, left out,
    may leave fewer."""
    return len(training_trajectories(duration)) * TrajectorySpec(duration=duration).ticks


def run(
    experiment: Experiment,
    base: RunConfig,
    reps: int,
    test_count: int = DEFAULT_TEST_TRAJECTORIES,
    ticks: int | None = None,
) -> Conclusion:
    """Run the experiment (module docstring) and write its files; return its findings."""
    duration = base.trajectories[0].duration
    plant = base.plant
    test, accepted = test_pool(experiment, duration, test_count, plant)
    test_digest = rows_digest(test)
    reference = score(rigid_prior(plant, "inverse"), test)
    floor = score(true_model(plant, "inverse"), test)
    rows: list[dict[str, object]] = [
        _result_row("all", "(none)", name, scores, 0, 0, 0.0, test_digest, len(test))
        for name, scores in ((REFERENCE_MODEL, reference), (FLOOR_MODEL, floor))
    ]
    nmse: dict[tuple[str, str], list[float]] = {}
    rmse: dict[tuple[str, str], list[float]] = {}
    for rep, episodes in enumerate(all_pools(experiment, base, reps)):
        pools = {c: pool_rows(logs) for c, logs in episodes.items()}
        count = ticks if ticks is not None else min(len(pool) for pool in pools.values())
        for condition in CONDITIONS:
            train, validation = subsample(pools[condition], count, rep)
            for kind in MODELS:
                started = time.perf_counter()
                model = fit_model(kind, plant, train, validation, rep)
                seconds = time.perf_counter() - started
                scores = score(model, test)
                nmse.setdefault((kind, condition), []).append(scores["nmse_mean"])
                rmse.setdefault((kind, condition), []).append(scores["rmse_mean"])
                rows.append(
                    _result_row(
                        rep,
                        condition,
                        kind,
                        scores,
                        len(train) + len(validation),
                        len(pools[condition]),
                        seconds,
                        test_digest,
                        len(test),
                    )
                )
                experiment.on_progress(
                    f"rep {rep}: {condition} {kind} nMSE {scores['nmse_mean']:.4f} "
                    f"({seconds:.1f} s)"
                )
    comparisons = compare(nmse)
    found = findings(nmse, comparisons, rmse=rmse, floor=floor)
    # The best selection against its runner-up, for the record: one test, so p_holm = p.
    written = [c.row() for c in comparisons] + [found.selection_test.row()]
    write_atomically(experiment.out / "results.csv", results_csv(rows))
    write_atomically(experiment.out / "comparisons.csv", results_csv(written))
    figure(
        experiment.out / FIGURE,
        {model: {c: nmse[(model, c)] for c in CONDITIONS} for model in MODELS},
        reference["nmse_mean"],
        floor["nmse_mean"],
    )
    train_rows = sorted({int(r["train_rows"]) for r in rows if r["model"] not in BASELINES})  # type: ignore[call-overload]
    setup = [
        f"{reps} repetitions (seeds 0..{reps - 1}); per repetition 3 specific runs (spiral, "
        f"random, pyramid) and 1 generic run (all three), {duration:g} s each; population "
        f"{base.pop}, {base.termination_text}, {plant_text(plant)}",
        "conditions: specific-front (every front member of each specific run, on its own "
        "trajectory), specific-knee (each specific run's knee on its own), specific-rerun (each "
        "specific knee on all three), generic-front and generic-knee (on all three), default "
        f"(DEFAULT_GAINS on all three), random ({RANDOM_CONTROLLERS} search-space draws with the "
        "repetition's seed, on all three)",
        f"equal ticks: {listed([str(n) for n in train_rows])} rows per condition and repetition "
        f"(a seeded subsample of its pool; {VALIDATION_FRACTION:.0%} of them validation for the "
        "networks' epoch choice)",
        f"test: {len(test):,} rows (digest {test_digest}) of the default gains and "
        f"{TEST_RANDOM_CONTROLLERS} random search-space controllers (seed {TEST_SEED}, draws "
        f"{', '.join(str(i) for i in accepted)}: the first whose torque steps stay within "
        f"{CHATTER_FACTOR:g} times the default's, i.e. that do not chatter) on {test_count} "
        f"held-out trajectories (fourier and random-kind seeds {FIRST_TEST_SEED}..), the same "
        "for every condition and repetition: controllers no condition tuned, so no condition is "
        "favoured by sharing its test controller",
        f"inverse dynamics (u from q, q̇, q̈, q̈ the Savitzky-Golay fit's `qdd_sg`); nMSE and "
        f"RMSE (N·m) means over {', '.join(MEAN_JOINTS)}; every pool, the test's too, holds "
        "calm episodes only (ran to their end without chatter: the dataset's rule)",
        f"baselines, untrained, on the same test rows: the rigid prior (the nominal arm every "
        f"learned model starts from) {baseline_text(reference)}; the true model (the simulated "
        f"plant's own inverse dynamics with its friction and rotor terms: its error is what the "
        f"columns' noise leaves, the floor) {baseline_text(floor)}",
        "test: paired t-test per tuned selection against the default and the random gains' "
        f"data, by repetition; Holm over all {len(comparisons)} comparisons of every model as one "
        "family",
        "raw numbers in `results.csv` and `comparisons.csv`, runs in `runs/`, extra episodes in "
        f"`{SIMULATED}/`",
    ]
    limitations = [
        "The residual model and the linear model's starting point share the rigid prior; its "
        "own errors (friction, the elastic joints) are what the data must teach, so the "
        "differences between conditions are differences in what is left.",
        "The validation rows are ticks drawn from the same episodes as the training rows, not "
        "held-out trajectories: the networks' epoch choice is the same rule for every condition, "
        "but optimistic.",
        "The test pool comes from three controllers on "
        f"{test_count} trajectories: a model's score depends on how alike those motions are to "
        "its training motions, which favours no condition by design but is one choice of test.",
        f"The tuning runs stop after {base.termination_text}"
        + (
            ": short runs, whose fronts may be far from converged."
            if base.generations is not None or base.evaluations is not None
            else "."
        ),
        f"{reps} repetitions: a paired t-test assumes roughly normal differences; with few "
        "repetitions only large effects can reach significance.",
    ]
    write_report(
        experiment.out / "report.md",
        setup=setup,
        means={"nmse_mean": spread(nmse), "rmse_mean": spread(rmse)},
        baselines={"rigid prior": reference, "true model (floor)": floor},
        comparisons=[*comparisons, found.selection_test],
        findings=found.text,
        limitations=limitations,
        figure=FIGURE,
    )
    return found


def baseline_text(scores: Mapping[str, float]) -> str:
    return f"nMSE {scores['nmse_mean']:.4f}, RMSE {scores['rmse_mean']:.3f} N·m"


def spread(
    values: Mapping[tuple[str, str], Sequence[float]],
) -> dict[tuple[str, str], tuple[float, float]]:
    """(model, condition) → (mean, sd) over repetitions (sd NaN for one)."""
    return {
        key: (statistics.fmean(v), statistics.stdev(v) if len(v) > 1 else math.nan)
        for key, v in values.items()
    }


def table(
    means: dict[tuple[str, str], tuple[float, float]],
    measure: str = "nMSE",
    baselines: Mapping[str, float] | None = None,
) -> list[str]:
    """(model, condition) → (mean, sd) of a test measure: conditions as rows, models as
    columns, "mean ± sd"; each untrained baseline's single score as a last row."""
    models = list(dict.fromkeys(model for model, _ in means))
    conditions = list(dict.fromkeys(condition for _, condition in means))

    def cell(mean: float, sd: float) -> str:
        return f"{mean:.4f}" if not math.isfinite(sd) else f"{mean:.4f} ± {sd:.4f}"

    rows = [
        [condition, *(cell(*means[(model, condition)]) for model in models)]
        for condition in conditions
    ]
    for name, value in (baselines or {}).items():
        rows.append([f"({name}, untrained)", *(f"{value:.4f}" for _ in models)])
    return markdown_table(["condition", *(f"{model} {measure}" for model in models)], rows)


def comparisons_table(comparisons: Sequence[PairedTTest]) -> list[str]:
    """Paired comparisons as a Markdown table; a difference below zero means lower nMSE. An
    untested value (too few repetitions) shows as a dash."""

    def number(value: float, fmt: str) -> str:
        return "–" if math.isnan(value) else format(value, fmt)

    return markdown_table(
        ["model", "condition", "against", "mean difference", "t", "p", "p (Holm)", "d_z", "n"],
        (
            [
                c.model,
                c.condition,
                c.against,
                number(c.mean_difference, "+.4f"),
                number(c.t, ".2f"),
                number(c.p, ".3g"),
                number(c.p_holm, ".3g"),
                number(c.d_z, "+.2f"),
                c.n,
            ]
            for c in comparisons
        ),
        text_columns=3,
    )


def write_report(
    path: Path,
    *,
    setup: Sequence[str],
    means: Mapping[str, dict[tuple[str, str], tuple[float, float]]],
    baselines: Mapping[str, Mapping[str, float]],
    comparisons: Sequence[PairedTTest],
    findings: str,
    limitations: Sequence[str],
    figure: str,
) -> None:
    """The dataset-value experiment's report.md: question, setup, a table per measure (`means`:
    a MEASURES column → (model, condition) → (mean, sd)), findings, comparisons, limitations,
    figure."""
    tables = []
    for key, values in means.items():
        tables += [
            f"## Test {MEASURES[key]} (mean ± sd over repetitions)",
            "",
            *table(values, MEASURES[key], {name: b[key] for name, b in baselines.items()}),
            "",
        ]
    lines = [
        "# The value of tuned controllers' data for learning the dynamics",
        "",
        "## Question",
        "",
        "Do tuned controllers' episodes teach a model of the arm's inverse dynamics more than the "
        "default gains' or random gains' episodes do, at equal ticks (the paper's claim of a "
        '"richer database")? Measured on one held-out test pool, against two untrained '
        "baselines: the rigid prior, and the true model's floor.",
        "",
        "## Design",
        "",
        *[f"- {line}" for line in setup],
        "",
        *tables,
        "## Findings",
        "",
        findings,
        "",
        "## Paired comparisons",
        "",
        "Difference = the condition's nMSE minus the other's, paired by repetition (below zero: "
        "its data taught more); paired t-test, Cohen's d_z = mean difference / sd of the "
        "differences; Holm's adjustment across every model's comparisons as one family (the "
        "last row, best selection against runner-up, is one test of its own).",
        "",
        *comparisons_table(comparisons),
        "",
        "## Limitations",
        "",
        *[f"- {line}" for line in limitations],
        "",
        f"![{figure}]({figure})",
        "",
    ]
    write_atomically(Path(path), "\n".join(lines).encode())


def figure(
    path: Path,
    nmse: dict[str, dict[str, list[float]]],
    reference: float | None = None,
    floor: float | None = None,
) -> None:
    """The dataset-value experiment: test nMSE per condition, one panel per model; a point per
    repetition (jittered sideways so equal values stay visible) and a bar at the mean. Dashed
    lines at `reference` (the untrained rigid prior's nMSE) and `floor` (the true model's), if
    given. Log scale when the values span more than a decade, as random gains' data can be far
    worse than the rest."""
    models = list(nmse)
    canvas = new_figure((4.0 * max(1, len(models)), 4.5))
    panels = canvas.subplots(1, max(1, len(models)), sharey=True, squeeze=False)[0]
    values = [v for per_model in nmse.values() for vs in per_model.values() for v in vs]
    lines_at = [v for v in (reference, floor) if v is not None]
    finite = [v for v in [*values, *lines_at] if math.isfinite(v) and v > 0]
    logarithmic = bool(finite) and max(finite) > 10 * min(finite)
    for axes, model in zip(panels, models, strict=False):
        conditions = list(nmse[model])
        for index, condition in enumerate(conditions):
            points = [v for v in nmse[model][condition] if math.isfinite(v)]
            if not points:
                continue
            offsets = [
                0.15 * (k / (len(points) - 1) - 0.5) if len(points) > 1 else 0.0
                for k in range(len(points))
            ]
            axes.scatter(
                [index + o for o in offsets], points, s=14, color="tab:blue", alpha=0.6, zorder=2
            )
            mean = sum(points) / len(points)
            axes.hlines(mean, index - 0.3, index + 0.3, color="black", linewidth=2, zorder=3)
        lines = ((reference, "grey", "rigid prior"), (floor, "tab:green", "true model"))
        for value, colour, label in lines:
            if value is not None and math.isfinite(value):
                axes.axhline(value, color=colour, linestyle="--", linewidth=1, label=label)
        if any(value is not None for value, _, _ in lines):
            axes.legend(loc="upper left", fontsize=8)
        axes.set_xticks(range(len(conditions)))
        axes.set_xticklabels(conditions, rotation=45, ha="right", fontsize=8)
        axes.set_title(model)
        axes.grid(True, axis="y", alpha=0.3)
        if logarithmic:
            axes.set_yscale("log")
    panels[0].set_ylabel("test nMSE (mean A1-A6)")
    save_png(canvas, path)


def _result_row(
    rep: int | str,
    condition: str,
    model: str,
    scores: Mapping[str, float],
    train_rows: int,
    pool_ticks: int,
    seconds: float,
    test_digest: str,
    test_rows: int,
) -> dict[str, object]:
    return {
        "rep": rep,
        "seed": rep,
        "condition": condition,
        "model": model,
        **scores,
        "train_rows": train_rows,
        "pool_ticks": pool_ticks,
        "fit_seconds": round(seconds, 3),
        "test_rows": test_rows,
        "test_digest": test_digest,
    }


def prepare(base: RunConfig, options: Mapping[str, Any]) -> RunConfig:
    """The base configuration as it is; ValueError naming --ticks if more rows are asked for
    than the smallest pool can hold."""
    ticks = options.get("ticks")
    duration = base.trajectories[0].duration
    if ticks is not None and ticks > smallest_pool(duration):
        raise ValueError(
            f"--ticks: {ticks} is more than the smallest pool holds at {duration:g} s "
            f"({smallest_pool(duration)} rows: three episodes)"
        )
    return base


def every_trajectory(base: RunConfig, options: Mapping[str, Any]) -> list[TrajectorySpec]:
    """Every trajectory the experiment's episodes follow: the training kinds and the test."""
    duration = base.trajectories[0].duration
    count = options.get("test_count", DEFAULT_TEST_TRAJECTORIES)
    return [*training_trajectories(duration), *test_trajectories(duration, count)]


EXPERIMENT = ExperimentSpec(
    name="dataset-value",
    robots=("iiwa14",),  # one arm's by design, as yet
    only_on="its learners read the iiwa 14's joint columns and dynamics (analytic/data)",
    summary="whether tuned controllers' data teach the arm's dynamics better, at equal ticks",
    run=run,
    options=(
        Option(
            "--test-trajectories",
            "test_count",
            "held-out test trajectories (fourier and random-kind, seeds 1000..)",
            str(DEFAULT_TEST_TRAJECTORIES),
            at_least(1),
            "N",
        ),
        Option(
            "--ticks",
            "ticks",
            # Fewer than 10 rows cannot hold a validation part and a training part worth the name.
            "training rows per condition and repetition  [default: the smallest pool's]",
            None,
            at_least(10),
            "N",
        ),
    ),
    duration=DEFAULT_DURATION,
    prepare=prepare,
    trajectories=every_trajectory,
)
