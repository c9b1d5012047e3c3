"""The tuning loop's guarantees with an in-process evaluator: no farm, no simulation, milliseconds.

The evaluator scores each candidate with tests.analytic.toy's function of its gains, which has a
real front for NSGA-II to find. The same guarantees are tested on a real farm in test_run.py.
"""

import itertools
import math
import random
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.evaluator import EpisodeResult
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import read_baseline, read_front, read_history, read_run
from gainfarm.analytic.tuning.run import RunProgress, TuningRun, upgrade
from gainfarm.analytic.view.run_report import write_run_report
from gainfarm.schemas import EpisodeSpec, Scores, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.trajectory import TrajectoryKind
from tests.analytic.toy import toy_scores

TINY = RunConfig(
    pop=6, seed=7, trajectories=(TrajectorySpec(kind="fourier", duration=0.5),), generations=3
)


class Shuffled(InProcessEvaluator):
    """Hands evaluations back in a random order, as a farm of many workers does."""

    def __init__(self, seed: int):
        super().__init__(scorer=toy_scores)
        self.order = random.Random(seed)
        self._queued: dict[str, EpisodeSpec] = {}

    def submit(self, specs: Mapping[str, EpisodeSpec]) -> None:
        self._queued.update(specs)

    def cancel(self, job_ids: Iterable[str]) -> None:
        for job_id in job_ids:
            self._queued.pop(job_id, None)
        super().cancel(job_ids)

    def results(self) -> Iterator[EpisodeResult]:
        while self._queued:
            job_ids = list(self._queued)
            self.order.shuffle(job_ids)
            batch = {job_id: self._queued.pop(job_id) for job_id in job_ids}
            super().submit(batch)
            yield from super().results()


class Interrupt(Exception):
    pass


def tune(
    directory: Path, config: RunConfig = TINY, report: bool = False, **hooks: object
) -> TuningRun:
    """A run of the toy problem; the figures and report (0.3 s of drawing) only if asked. The run
    returned is closed (its lock released), as one interrupted is."""
    with TuningRun.create(directory, config) as run:
        evaluator = InProcessEvaluator(scorer=toy_scores)
        run.run(evaluator, **hooks)
        if report:
            run.baseline(evaluator)
            write_run_report(run)
    return run


def test_a_generational_run_records_every_generation_and_a_non_dominated_front(
    tmp_path: Path,
) -> None:
    run = tune(tmp_path / "run", TINY.model_copy(update={"generations": 5}))
    history = read_history(run.directory / "history.csv")
    assert [row.generation for row in history] == [1, 2, 3, 4, 5]
    assert [row.evaluations for row in history] == [6, 12, 18, 24, 30]
    hypervolumes = [row.hypervolume for row in history]
    assert all(later >= earlier for earlier, later in itertools.pairwise(hypervolumes))
    assert hypervolumes[-1] > hypervolumes[0] > 0  # the toy problem has room to improve
    front = read_front(run.directory / "front.csv")
    for a, b in itertools.permutations(front, 2):
        assert not (a.f_acc <= b.f_acc and a.f_t <= b.f_t and a.objectives != b.objectives)
    for f_acc, f_t in run.state.evaluated:
        assert not any(f_acc < m.f_acc and f_t < m.f_t for m in front)
    assert run.state.stopped == "5 generations"


def test_the_run_directory_reads_back_without_the_checkpoint(tmp_path: Path) -> None:
    run = tune(tmp_path / "run")
    (run.directory / "checkpoint.pkl").unlink()
    record = read_run(run.directory)
    assert record.config == TINY
    assert record.stopped == run.state.stopped == "3 generations"
    assert record.evaluations == 18 and record.evaluated == run.state.evaluated
    assert [m.objectives for m in record.front] == [
        m.objectives for m in run.state.evolution.front()
    ]
    assert record.front == run.front()


def test_the_front_is_the_same_whatever_order_the_results_come_in(tmp_path: Path) -> None:
    fronts = []
    for seed in range(3):
        run = TuningRun.create(tmp_path / f"run{seed}", TINY)
        run.run(Shuffled(seed))
        fronts.append((run.directory / "front.csv").read_bytes())
    in_order = tune(tmp_path / "in-order")
    assert fronts == [(in_order.directory / "front.csv").read_bytes()] * 3


def test_the_same_seed_gives_the_same_front_and_another_seed_another(tmp_path: Path) -> None:
    one, two = tune(tmp_path / "one"), tune(tmp_path / "two")
    other = tune(tmp_path / "other", TINY.model_copy(update={"seed": 8}))
    front = (one.directory / "front.csv").read_bytes()
    assert (two.directory / "front.csv").read_bytes() == front
    assert (other.directory / "front.csv").read_bytes() != front


@pytest.mark.parametrize(("record_seconds", "written"), [(0.0, 2), (3600.0, 1)])
def test_a_stopped_and_resumed_run_ends_where_an_uninterrupted_one_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, record_seconds: float, written: int
) -> None:
    # Records written as each generation ends, or (fast generations) only the first one's: a
    # resume runs again whatever generations were not written, to the same front.
    monkeypatch.setattr("gainfarm.analytic.tuning.books.RECORD_SECONDS", record_seconds)
    whole = tune(tmp_path / "whole")

    def stop_in_generation_two(progress: RunProgress) -> None:
        if progress.generation == 2 and progress.evaluations > 14:
            raise Interrupt  # as Ctrl-C would, halfway through a generation

    stopped = tmp_path / "stopped"
    with pytest.raises(Interrupt):
        tune(stopped, on_progress=stop_in_generation_two)
    assert len(read_history(stopped / "history.csv")) == written
    resumed = TuningRun.open(stopped)
    assert not resumed.finished and len(resumed.state.history) == written
    resumed.run(InProcessEvaluator(scorer=toy_scores))
    assert (stopped / "front.csv").read_bytes() == (whole.directory / "front.csv").read_bytes()
    assert (stopped / "evaluated.csv").read_bytes() == (
        whole.directory / "evaluated.csv"
    ).read_bytes()


def test_a_run_stopped_before_its_first_generation_starts_again(tmp_path: Path) -> None:
    def stop_at_once(progress: RunProgress) -> None:
        raise Interrupt

    with pytest.raises(Interrupt):
        tune(tmp_path / "run", on_progress=stop_at_once)
    assert read_run(tmp_path / "run").stopped is None
    resumed = TuningRun.open(tmp_path / "run")
    resumed.run(InProcessEvaluator(scorer=toy_scores))
    assert resumed.state.stopped == "3 generations"


def test_a_steady_state_run_records_a_row_every_pop_evaluations(tmp_path: Path) -> None:
    config = TINY.model_copy(update={"asynchronous": True, "generations": 4})
    run = tune(tmp_path / "run", config, report=True)
    history = read_history(run.directory / "history.csv")
    assert [row.evaluations for row in history] == [6, 12, 18, 24]
    hypervolumes = [row.hypervolume for row in history]
    assert all(later >= earlier for earlier, later in itertools.pairwise(hypervolumes))
    assert len(run.state.evaluated) >= 24
    assert "steady-state" in (run.directory / "report.md").read_text()


class Growing(InProcessEvaluator):
    """A farm of one worker that grows to eight once its first dozen results are in; records
    how many jobs were in flight at each submission."""

    def __init__(self) -> None:
        super().__init__(scorer=toy_scores)
        self.done = 0
        self.in_flight: list[int] = []

    @property
    def capacity(self) -> int:
        return 1 if self.done < 12 else 8

    def submit(self, specs: Mapping[str, EpisodeSpec]) -> None:
        super().submit(specs)
        self.in_flight.append(self.pending)

    def results(self, timeout: float | None = None) -> Iterator[EpisodeResult]:
        for result in super().results(timeout):
            self.done += 1
            yield result


def test_a_steady_state_run_keeps_more_candidates_in_flight_when_the_farm_grows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        "gainfarm.analytic.tuning.steady_state.CAPACITY_SECONDS", 0.0
    )  # look up the farm every time
    farm = Growing()
    config = TINY.model_copy(update={"asynchronous": True, "generations": 5})
    TuningRun.create(tmp_path / "run", config).run(farm)
    first_generation, steady = farm.in_flight[0], farm.in_flight[1:]
    assert first_generation == config.pop  # generational, as every steady-state run starts
    assert max(steady[:8]) == 2  # two per worker on a farm of one
    assert max(steady) == steady[-1] == 16  # and two per worker on the farm of eight it became


def test_a_run_stops_after_its_evaluations(tmp_path: Path) -> None:
    config = TINY.model_copy(update={"generations": None, "evaluations": 20})
    run = tune(tmp_path / "run", config)
    assert run.state.stopped == "24 evaluations"  # whole generations: the first past 20
    assert read_run(run.directory).stopped == "24 evaluations"


def test_a_steady_state_run_stops_at_its_evaluations_exactly(tmp_path: Path) -> None:
    """Not at the end of the "generation" (every pop evaluations) past it: no candidate is asked
    beyond the budget, and the last row is a partial generation of its own."""
    config = TINY.model_copy(update={"generations": None, "evaluations": 20, "asynchronous": True})
    evaluator = InProcessEvaluator(scorer=toy_scores)
    with TuningRun.create(tmp_path / "run", config) as run:
        run.run(evaluator)
    assert run.state.stopped == "20 evaluations"
    assert len(run.state.evaluated) == 20 and evaluator.pending == 0
    history = read_history(run.directory / "history.csv")
    assert [(row.generation, row.evaluations) for row in history] == [
        (1, 6),
        (2, 12),
        (3, 18),
        (4, 20),
    ]
    assert len((run.directory / "evaluated.csv").read_text().splitlines()) == 1 + 20


@pytest.mark.parametrize("asynchronous", [False, True])
def test_progress_is_told_once_as_each_generation_ends(tmp_path: Path, asynchronous: bool) -> None:
    told: list[RunProgress] = []
    config = TINY.model_copy(update={"asynchronous": asynchronous})
    run = tune(tmp_path / "run", config, on_progress=told.append)
    ended = [step for step in told if step.ended]
    assert [(s.generation, s.evaluations) for s in ended] == [(1, 6), (2, 12), (3, 18)]
    for step, row in zip(ended, run.state.history, strict=True):
        assert (step.hypervolume, step.best_f_acc) == (row.hypervolume, row.best_f_acc)
    first = [step for step in told if step.evaluations <= 6 and not step.ended]
    assert first and all(math.isnan(s.hypervolume) and math.isnan(s.best_f_acc) for s in first)


def test_a_run_stops_when_the_hypervolume_stops_growing(tmp_path: Path) -> None:
    config = TINY.model_copy(update={"generations": None, "tolerance": 0.05, "window": 2})
    run = tune(tmp_path / "run", config)
    hypervolumes = [row.hypervolume for row in run.state.history]
    assert run.state.stopped.startswith("converged after")
    assert hypervolumes[-1] - hypervolumes[-3] <= 0.05 * hypervolumes[-3]
    assert all(  # and not a generation earlier
        later - earlier > 0.05 * earlier
        for earlier, later in zip(hypervolumes[:-3], hypervolumes[2:-1], strict=True)
    )


def test_keep_front_keeps_only_the_front_members_logs(tmp_path: Path) -> None:
    config = TINY.model_copy(update={"keep": "front"})
    run = TuningRun.create(tmp_path / "run", config)
    run.run(InProcessEvaluator(tmp_path / "run"))  # real episodes, logs kept
    kept = sorted(path.name for path in (run.directory / "episodes").glob("*.mcap"))
    listed = sorted(Path(episode).name for m in run.front() for episode in m.logs)
    assert kept == listed and 1 <= len(kept) < 18


def test_a_run_that_stops_leaves_nothing_in_flight_for_the_next(tmp_path: Path) -> None:
    evaluator = InProcessEvaluator(scorer=toy_scores)
    steady = TINY.model_copy(update={"asynchronous": True})
    first = TuningRun.create(tmp_path / "first", steady)
    first.run(evaluator)
    assert evaluator.pending == 0  # the candidates in flight when it stopped were dropped

    def stop_in_generation_two(progress: RunProgress) -> None:
        if progress.generation == 2 and progress.evaluations > 14:
            raise Interrupt

    second = TuningRun.create(tmp_path / "second", TINY)
    with pytest.raises(Interrupt), second:
        second.run(evaluator, stop_in_generation_two)
    assert evaluator.pending == 0
    resumed = TuningRun.open(tmp_path / "second")
    resumed.run(evaluator)  # the same evaluator: nothing stale comes back
    assert (tmp_path / "second" / "front.csv").read_bytes() == (
        tune(tmp_path / "whole").directory / "front.csv"
    ).read_bytes()


def test_a_run_from_before_front_json_is_upgraded_from_its_checkpoint(tmp_path: Path) -> None:
    run = tune(tmp_path / "run")
    expected = read_run(run.directory)
    for name in ("front.json", "evaluated.csv"):  # what runs of earlier versions lack
        (run.directory / name).unlink()
    with pytest.raises(FileNotFoundError):
        read_run(run.directory)
    upgrade(run.directory)
    assert read_run(run.directory) == expected


def pyramid_rough(spec: EpisodeSpec) -> Scores:
    """The toy's scores, with a pyramid's torque steps 40 times a spiral's, as the arm's are."""
    scores = toy_scores(spec)
    rough = 40.0 if spec.trajectory.kind == TrajectoryKind.pyramid else 1.0
    return scores.model_copy(update={"f_t": scores.f_t * rough})


def test_a_generic_run_weighs_each_trajectory_as_its_config_says(tmp_path: Path) -> None:
    both = (TrajectorySpec(duration=1.0), TrajectorySpec(kind="pyramid", duration=1.0))
    weights = ((0.5, 40 / 41), (0.5, 1 / 41))  # each trajectory's f_t counts alike
    config = RunConfig(pop=4, trajectories=both, generations=2, objective_weights=weights)
    run = TuningRun.create(tmp_path / "run", config)
    with run:
        run.run(InProcessEvaluator(scorer=pyramid_rough))
    evaluated = read_run(run.directory).evaluated
    assert len(evaluated) == 8
    # Each point is the weighted mean: the spiral's f_acc, and 80/41 of the spiral's f_t
    # (unweighted, the pyramid would make it 20.5 times).
    expected = set()
    for gains in run.state.provenance:
        alone = toy_scores(EpisodeSpec(gains=gains, trajectory=both[0]))
        expected.add((alone.f_acc, 80 / 41 * alone.f_t))
    assert len(expected) == len(set(evaluated))
    for point in evaluated:
        assert any(point == pytest.approx(other, rel=1e-12) for other in expected)


class Refusing(InProcessEvaluator):
    """An evaluator that must not be asked for anything."""

    def submit(self, specs: Mapping[str, EpisodeSpec], avoid: object = None) -> None:
        raise AssertionError(f"asked to run {sorted(specs)}")


def test_a_reported_run_scores_the_default_gains_once_as_it_scores_its_candidates(
    tmp_path: Path,
) -> None:
    both = (TrajectorySpec(duration=1.0), TrajectorySpec(kind="pyramid", duration=1.0))
    weights = ((0.5, 40 / 41), (0.5, 1 / 41))
    config = RunConfig(pop=4, trajectories=both, generations=1, objective_weights=weights)
    with TuningRun.create(tmp_path / "run", config) as run:
        run.run(InProcessEvaluator(scorer=pyramid_rough))
        assert run.baseline() is None  # not asked for yet
        evaluated = run.baseline(InProcessEvaluator(scorer=pyramid_rough))
        baseline = run.baseline(Refusing())  # kept in baseline.json: not asked again
        write_run_report(run)  # nor when the figures are drawn
    assert baseline == evaluated
    assert "default gains" in (run.directory / "report.md").read_text()
    # The same weighted mean as a candidate's: the spiral's f_acc, 80/41 of its f_t.
    alone = toy_scores(EpisodeSpec(gains=DEFAULT_GAINS, trajectory=both[0]))
    assert baseline is not None and baseline.gains == DEFAULT_GAINS and not baseline.diverged
    assert baseline.objectives == pytest.approx((alone.f_acc, 80 / 41 * alone.f_t), rel=1e-12)
    assert [e["job_id"] for e in baseline.episodes] == ["baseline-t0", "baseline-t1"]
    assert read_baseline(run.directory / "baseline.json") == baseline
    assert "| default gains (not tuned) |" in (run.directory / "report.md").read_text()


def test_an_unreported_run_evaluates_no_baseline(tmp_path: Path) -> None:
    with TuningRun.create(tmp_path / "run", TINY) as run:
        run.run(InProcessEvaluator(scorer=toy_scores))
        assert run.baseline() is None
    assert not (run.directory / "baseline.json").exists()
