"""The optimiser comparison at toy size: in this process, on the toy objective
(tests.analytic.toy), so that a whole experiment takes seconds; and its command's refusals."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import algorithms, algorithms_measures
from gainfarm.analytic.experiments import statistics as analytic_stats
from gainfarm.analytic.experiments.normalisation import Normalisation, non_dominated
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.experiments.statistics import holm
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import HistoryRow, read_run
from gainfarm.analytic.tuning.termination import Termination
from gainfarm.schemas import EpisodeSpec, Scores, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.objectives import NO_EPISODE, f_acc, f_t, f_t_joint
from gainfarm.worker.episode import run_episode
from tests.analytic.experiments.common import refusal
from tests.analytic.toy import toy_scores

BUDGET = 24
# A rule loose enough to fire within six generations of four: the default needs longer runs.
BASE = RunConfig(
    pop=4,
    trajectories=(TrajectorySpec(duration=1.0),),
    evaluations=BUDGET,
    tolerance=0.02,
    window=2,
    keep="front",
)
ALGORITHMS = ("nsga2", "random")
FIXED = (8, 16, 24, 40)  # the budget and beyond it: compared at 8 and 16 only
SCALINGS = ("raw", "log")
REPS = 2
PNG = b"\x89PNG\r\n\x1a\n"
RESULT_COLUMNS = [
    "algorithm",
    "scaling",
    "rep",
    "seed",
    "evaluations",
    "hypervolume",
    "hv_at_8",
    "hv_at_16",
    "best_f_acc_mm",
    "evaluations_to_99",
    "stopped_by_rule_at",
    "hv_at_rule_stop",
]
# A diverged arm that fell late and then hardly moved: the smoothest torque of all, and an
# error within the toy's range; a penalty only the divergence reveals.
PENALTY = (0.5, 1e-3)


def rows(path: Path) -> list[dict[str, str]]:
    with path.open() as stream:
        return list(csv.DictReader(stream))


def in_process(study: str, directory: Path) -> InProcessEvaluator:
    return InProcessEvaluator(scorer=toy_scores)


def soft_arms_diverge(spec: EpisodeSpec) -> Scores:
    """The toy objective, but a shoulder far softer than the default's lets the arm fall."""
    if spec.gains.kp[1] < 0.2 * DEFAULT_GAINS.kp[1]:
        f_acc, f_t = PENALTY
        # With the damping margin a worker measures before the episode runs (its log's
        # metadata), as the default gains' on the realistic plant.
        return Scores(
            f_acc=f_acc,
            f_t=f_t,
            max_error=f_acc,
            saturated_fraction=0.0,
            diverged=True,
            ticks=1,
            damping=0.013,
        )
    return toy_scores(spec)


@pytest.fixture(scope="module")
def out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One experiment, run once for the tests that read it."""
    directory = tmp_path_factory.mktemp("algorithms")
    algorithms.run(
        Experiment(directory, in_process), BASE, REPS, ALGORITHMS, SCALINGS, budgets=FIXED
    )
    return directory


def by_condition(results: list[dict[str, str]], column: str) -> dict[str, list[float]]:
    found: dict[str, list[float]] = {}
    for row in results:
        found.setdefault(f"{row['algorithm']}-{row['scaling']}", []).append(float(row[column]))
    return found


@pytest.mark.slow
def test_a_row_per_run_each_on_the_same_budget(out: Path) -> None:
    results = rows(out / "results.csv")
    assert list(results[0]) == RESULT_COLUMNS
    assert [(r["algorithm"], r["scaling"], r["rep"], r["seed"]) for r in results] == [
        (a, s, str(rep), str(rep)) for a in ALGORITHMS for s in SCALINGS for rep in range(REPS)
    ]
    assert {r["evaluations"] for r in results} == {str(BUDGET)}
    assert all(0 < float(r["hypervolume"]) <= 1 and float(r["best_f_acc_mm"]) > 0 for r in results)
    for r in results:
        run = read_run(out / "runs" / f"{r['algorithm']}-{r['scaling']}-rep{r['rep']}")
        assert (run.config.algorithm, run.config.objective_scaling) == (
            r["algorithm"],
            r["scaling"],
        )
        assert run.config.evaluations == BUDGET and len(run.evaluated) == BUDGET
        reached = r["evaluations_to_99"]
        assert reached == "" or 0 < int(reached) <= BUDGET


def test_the_hypervolume_is_that_of_every_evaluated_point_in_the_experiments_space(
    out: Path,
) -> None:
    space = json.loads((out / "normalisation.json").read_text())[algorithms_measures.SPACE]
    normalisation = Normalisation(tuple(space["ideal"]), tuple(space["nadir"]))
    for r in rows(out / "results.csv"):
        run = read_run(out / "runs" / f"{r['algorithm']}-{r['scaling']}-rep{r['rep']}")
        # No replication in this process: the front is exactly the evaluated points' own.
        assert sorted(non_dominated(run.evaluated)) == sorted(m.objectives for m in run.front)
        assert float(r["hypervolume"]) == normalisation.hypervolume(non_dominated(run.evaluated))
        assert float(r["best_f_acc_mm"]) == min(f_acc for f_acc, _ in run.evaluated) * 1000


def test_stats_compare_each_condition_with_the_first_as_scipy_does(out: Path) -> None:
    found = rows(out / "stats.csv")
    assert {r["experiment"] for r in found} == {"algorithms"}
    others = ["nsga2-log", "random-raw", "random-log"]
    assert [(r["comparison"], r["metric"]) for r in found[:6]] == [
        (f"{c} vs nsga2-raw", metric) for metric in ("hypervolume", "best_f_acc_mm") for c in others
    ]
    results = rows(out / "results.csv")
    for metric in ("hypervolume", "best_f_acc_mm"):
        values = by_condition(results, metric)
        reference = values["nsga2-raw"]
        for row in (
            r for r in found if r["metric"] == metric and "vs nsga2-raw" in r["comparison"]
        ):
            other = values[row["comparison"].split(" vs ")[0]]
            assert float(row["median_a"]) == np.median(other)
            assert float(row["median_b"]) == np.median(reference)
            assert (int(row["n_a"]), int(row["n_b"])) == (REPS, REPS)
            if row["comparison"].startswith("nsga2-"):  # the same algorithm: paired by seed
                expected = (
                    1.0
                    if other == reference
                    else stats.wilcoxon(other, reference, alternative="two-sided").pvalue
                )
            else:
                expected = stats.mannwhitneyu(other, reference, alternative="two-sided").pvalue
            assert float(row["p_value"]) == pytest.approx(expected)


def test_the_convergence_rule_is_checked_on_the_first_algorithms_runs(out: Path) -> None:
    results = rows(out / "results.csv")
    first = [r for r in results if r["algorithm"] == "nsga2"]
    assert all(r["stopped_by_rule_at"] for r in first)  # the loose rule fires in every one
    for r in first:
        assert 0 < int(r["stopped_by_rule_at"]) <= BUDGET
        assert float(r["hv_at_rule_stop"]) <= float(r["hypervolume"])
    (check,) = [r for r in rows(out / "stats.csv") if "convergence rule" in r["comparison"]]
    at_stop, at_budget = (
        [float(r[column]) for r in first] for column in ("hv_at_rule_stop", "hypervolume")
    )
    assert int(check["n_a"]) == int(check["n_b"]) == len(first)
    assert float(check["median_a"]) == np.median(at_budget)
    assert float(check["median_b"]) == np.median(at_stop)
    assert (
        "The convergence rule (hypervolume gain below 2% over 2 generations"
        in (out / "report.md").read_text()
    )


def test_the_report_tables_every_condition_and_the_classical_baseline(out: Path) -> None:
    report = (out / "report.md").read_text()
    for condition in (
        "| NSGA-II, raw | 2 |",
        "| NSGA-II, log f_t | 2 |",
        "| uniform random search, raw | 2 |",
    ):
        assert condition in report
    assert "| classical rule (16 controllers), no GA |" in report
    assert "| default gains, no GA |" in report
    # 2 against 2 repetitions, Holm over 3: the report says the data cannot decide.
    assert "cannot decide between uniform random search, raw and NSGA-II, raw" in report
    assert "more repetitions are needed" in report
    assert (out / "algorithms.png").read_bytes().startswith(PNG)


def test_the_normalisation_leaves_penalty_points_out(tmp_path: Path) -> None:
    experiment = Experiment(tmp_path, lambda name, _: InProcessEvaluator(scorer=soft_arms_diverge))
    algorithms.run(experiment, BASE.model_copy(update={"evaluations": 8}), 1, ["nsga2"])
    # Soft controllers let the arm fall: penalties, and non-dominated ones (the smoothest
    # torque of all), which would set the nadir's f_acc and the ideal's f_t.
    assert PENALTY in experiment.penalised
    # A run's own front holds one too, flagged diverged in its front.csv.
    [front] = [read_run(path).front for path in (tmp_path / "runs").iterdir()]
    assert PENALTY in [m.objectives for m in front if m.diverged]
    space = json.loads((tmp_path / "normalisation.json").read_text())[algorithms_measures.SPACE]
    assert space["nadir"][0] < PENALTY[0] and space["ideal"][1] > PENALTY[1]
    assert all(0 <= float(r["hypervolume"]) <= 1 for r in rows(tmp_path / "results.csv"))


# --- the pure parts ------------------------------------------------------------------------------


def test_checkpoints_are_every_generation_and_the_budget() -> None:
    assert algorithms_measures.checkpoints(30, 600) == list(range(30, 601, 30))
    assert algorithms_measures.checkpoints(4, 10) == [4, 8, 10]


def test_the_hypervolume_curve_grows_with_the_points_and_ignores_penalties() -> None:
    normalisation = Normalisation(ideal=(0.1, 1.0), nadir=(0.3, 10.0))
    diverged = (0.2, 2.0)  # inside the box: it would add to the hypervolume if it counted
    points = [(0.3, 10.0), NO_EPISODE, (0.1, 10.0), diverged, (0.3, 1.0)]
    curve = algorithms_measures.hypervolume_curve(points, [1, 3, 4, 5], normalisation, {diverged})
    assert curve[0] < curve[1] == curve[2] < curve[3] <= 1
    assert curve[3] == normalisation.hypervolume([(0.1, 10.0), (0.3, 1.0)])
    assert algorithms_measures.evaluations_to(curve, [1, 3, 4, 5], curve[1]) == 3
    assert algorithms_measures.evaluations_to(curve, [1, 3, 4, 5], 2.0) is None


def test_the_rule_stops_where_the_run_would_have() -> None:
    history = [
        HistoryRow(g, 10 * g, hv, (0.01, 1.0), 0.0)
        for g, hv in enumerate([0.5, 0.6, 0.7, 0.701, 0.702, 0.703, 0.8], start=1)
    ]
    assert algorithms_measures.rule_stop(history, Termination(tolerance=0.005, window=2)) == 50
    assert algorithms_measures.rule_stop(history, Termination(tolerance=0.005, window=5)) is None


@pytest.mark.parametrize(
    ("names", "message"),
    [
        (["nsga2", "cmaes"], "unknown algorithm 'cmaes': one of nsga2, "),
        (["nsga2", "random", "nsga2"], "algorithm 'nsga2' given twice"),
    ],
)
def test_an_unknown_or_repeated_algorithm_is_refused(names: list[str], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        algorithms.check_names(names, ("nsga2", "random"), "algorithm")


def test_the_experiment_needs_a_budget(tmp_path: Path) -> None:
    unbudgeted = BASE.model_copy(update={"evaluations": None})
    with pytest.raises(ValueError, match="budget"):
        algorithms.run(Experiment(tmp_path, in_process), unbudgeted, 1, ["nsga2"])
    assert not (tmp_path / "runs").exists()


def test_holm_adjusts_the_family_and_the_smallest_p_it_can_reach() -> None:
    five_against_five = [[0.1 * i + j for j in range(5)] for i in range(1, 8)]
    reference = [0.0] * 5
    family = {
        algorithms_measures.Condition(f"a{i}", "raw"): analytic_stats.compare(values, reference)
        for i, values in enumerate(five_against_five)
    }
    for size, decidable in ((3, True), (7, False)):
        chosen = dict(list(family.items())[:size])
        adjusted = analytic_stats.holm_adjusted(chosen)
        assert [r.p_value for r in adjusted.values()] == holm([r.p_value for r in chosen.values()])
        # Mann-Whitney 5 against 5 reaches 2/252 alone: 3 of them can still decide, 7 cannot.
        assert all(analytic_stats.decidable(r) == decidable for r in adjusted.values())


def test_the_rule_check_needs_a_run_the_rule_stopped() -> None:
    never = algorithms_measures.RunMeasure(24, 0.5, 0.01, [0.4, 0.5], None, None)
    stopped = algorithms_measures.RunMeasure(24, 0.5, 0.01, [0.4, 0.5], 12, 0.4)
    assert algorithms_measures.check_rule([never]) is None
    check = algorithms_measures.check_rule([never, stopped])
    assert check is not None and check.paired and (check.n_a, check.median_b) == (1, 0.4)


# --- the command line ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (
            ["--algorithms", "nsga2,cmaes"],
            "--algorithms: unknown algorithm 'cmaes': one of nsga2, ",
        ),
        (["--algorithms", "nsga2,random,nsga2"], "--algorithms: algorithm 'nsga2' given twice"),
        (["--objective-scaling", "raw,sqrt"], "--objective-scaling: unknown objective scaling"),
        (["--generations", "3"], "--generations: the algorithms experiment compares on a budget"),
        (["--torque-measure", "sum"], "--torque-measure: unknown torque measure 'sum': one of raw"),
    ],
)
@pytest.mark.slow
def test_the_algorithms_experiment_refuses_bad_options_in_one_line_before_anything_is_written(
    tmp_path: Path, arguments: list[str], message: str
) -> None:
    assert refusal(tmp_path, "algorithms", *arguments).startswith(message)


# --- the measures that separate methods: fixed budgets, attainment, Holm ------------------------


def test_each_run_is_compared_at_the_fixed_budgets_below_its_own(out: Path) -> None:
    space = json.loads((out / "normalisation.json").read_text())[algorithms_measures.SPACE]
    normalisation = Normalisation(tuple(space["ideal"]), tuple(space["nadir"]))
    for r in rows(out / "results.csv"):
        run = read_run(out / "runs" / f"{r['algorithm']}-{r['scaling']}-rep{r['rep']}")
        for k in (8, 16):  # every toy point keeps the limits: each is feasible
            first = normalisation.hypervolume(non_dominated(run.evaluated[:k]))
            assert float(r[f"hv_at_{k}"]) == first <= float(r["hypervolume"])
    report = (out / "report.md").read_text()
    assert "| median hypervolume after 8 | median hypervolume after 16 |" in report
    assert "hypervolume after 16 evaluations: cannot decide" in report
    assert "- random-raw against nsga2-raw: after 8: " in report  # attainment differences


def test_holm_adjusts_every_hypervolume_claim_as_one_family(out: Path) -> None:
    found = rows(out / "stats.csv")
    hypervolume = [
        r
        for r in found
        if r["metric"].startswith("hypervolume") and r["comparison"].endswith(" vs nsga2-raw")
    ]
    assert sorted({r["metric"] for r in hypervolume}) == [
        "hypervolume",
        "hypervolume_at_16",
        "hypervolume_at_8",
    ]
    assert len(hypervolume) == 3 * 3  # three conditions against the reference, three budgets
    adjusted = holm([float(r["p_value"]) for r in hypervolume])
    assert [float(r["p_holm"]) for r in hypervolume] == pytest.approx(adjusted)
    errors = [r for r in found if r["metric"] == "best_f_acc_mm"]
    adjusted = holm([float(r["p_value"]) for r in errors])
    assert [float(r["p_holm"]) for r in errors] == pytest.approx(adjusted)
    (rule,) = [r for r in found if "convergence rule" in r["comparison"]]
    assert rule["p_holm"] == rule["p_value"]  # a test of its own


def test_the_hypervolume_curve_counts_feasible_points_only() -> None:
    normalisation = Normalisation(ideal=(0.1, 1.0), nadir=(0.3, 10.0))
    points = [(0.3, 10.0), (0.1, 1.0), (0.2, 5.0)]
    curve = algorithms_measures.hypervolume_curve(
        points, [2, 3], normalisation, kept=[True, False, True]
    )
    assert curve == [
        normalisation.hypervolume([(0.3, 10.0)]),
        normalisation.hypervolume([(0.3, 10.0), (0.2, 5.0)]),
    ]


def test_attainment_differences_count_each_sides_own_region() -> None:
    normalisation = Normalisation(ideal=(0.0, 1.0), nadir=(0.5, 100.0))
    accurate = [[(0.05, 100.0)], [(0.05, 100.0)]]  # each repetition's front
    smooth = [[(0.5, 1.0)], [(0.5, 1.0)]]
    only_a, only_b = algorithms_measures.attainment_difference(accurate, smooth, normalisation)
    both = normalisation.hypervolume([(0.05, 100.0), (0.5, 1.0)])
    assert only_a == pytest.approx(both - normalisation.hypervolume([(0.5, 1.0)]))
    assert only_b == pytest.approx(both - normalisation.hypervolume([(0.05, 100.0)]))
    assert only_a > 0 and only_b > 0  # the fronts cross: each attains a region of its own
    assert algorithms_measures.attainment_difference(accurate, accurate, normalisation) == (
        0.0,
        0.0,
    )


def test_tpe_runs_told_one_result_at_a_time_the_others_generationally(tmp_path: Path) -> None:
    pytest.importorskip("optuna")
    base = BASE.model_copy(update={"evaluations": 10})
    algorithms.run(Experiment(tmp_path, in_process), base, 1, ["random", "tpe"], budgets=(5,))
    for algorithm, asynchronous in (("random", False), ("tpe", True)):
        run = read_run(tmp_path / "runs" / f"{algorithm}-raw-rep0")
        assert run.config.asynchronous is asynchronous
        # a steady state stops at the budget exactly; generations of four go past it
        assert len(run.evaluated) == (10 if asynchronous else 12)
    assert "tpe in a steady state" in (tmp_path / "report.md").read_text()


def test_the_per_joint_torque_measure_is_what_every_run_and_baseline_minimises(
    tmp_path: Path,
) -> None:
    """Real episodes, half a second each: the objectives are the simulated arm's."""
    # No limits: random gains break them, and the front would be empty.
    unlimited = Limits(torque_step=None, saturated_fraction=None, speed=None, chatter=None)
    trajectory = TrajectorySpec(kind="fourier", duration=0.5)
    base = BASE.model_copy(
        update={"pop": 4, "evaluations": 4, "trajectories": (trajectory,), "limits": unlimited}
    )
    experiment = Experiment(tmp_path, lambda study, directory: InProcessEvaluator())
    algorithms.run(experiment, base, 1, ["random"], budgets=(), torque_measure="per-joint")
    run = read_run(tmp_path / "runs" / "random-raw-rep0")
    assert run.config.objectives == ("f_acc", "f_t_joint")
    member = run.front[0]
    log = run_episode(EpisodeSpec(gains=member.gains, trajectory=trajectory, plant=base.plant))
    assert member.objectives == pytest.approx((f_acc(log), f_t_joint(log)))
    assert f_t_joint(log) != pytest.approx(f_t(log))
    # The baselines are scored alike: the default gains' point is per-joint too.
    [default] = experiment.evaluate_gains("again", [DEFAULT_GAINS], trajectory, run.config)
    log = run_episode(EpisodeSpec(gains=DEFAULT_GAINS, trajectory=trajectory, plant=base.plant))
    assert default == pytest.approx((f_acc(log), f_t_joint(log)))
    assert "`--torque-measure per-joint`" in (tmp_path / "report.md").read_text()
