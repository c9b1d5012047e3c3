"""Validation by a referee inside a tuning run, in milliseconds: a stand-in farm of named
workers (the evaluator seam), one of which lies about the jobs it runs, and an honest stand-in
for the referee (the analytic's own process on a real farm)."""

import hashlib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus, Fetched, Wanted
from gainfarm.analytic.evaluators.replication import Ledger, sized_rate, validate
from gainfarm.analytic.experiments.normalisation import non_dominated
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import hypervolume
from gainfarm.analytic.tuning.records import read_evaluated, read_validation
from gainfarm.analytic.tuning.run import RunProgress, TuningRun
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from tests.analytic.toy import claimed_failure, toy_scores

# Spot checks at a fixed 0.05 (the default sizes them for this small run at 0.98: every
# episode), so that the front's own refereeing is what these tests see.
CONFIG = RunConfig(pop=8, generations=4, seed=3, spot_checks=0.05)


class ToyFarm:
    """Workers take jobs in turn, skipping any a job avoids or the farm distrusts; a liar
    returns a log a little better than the truth; a boaster returns the true log and claims
    better scores than it has; a saboteur claims worse ones; a failer says every episode it
    runs failed. The workers keep the logs: with
    `log_dir`, `fetch` writes each wanted one there and scores it truly (the toy log is the
    spec); without, there are none."""

    def __init__(
        self,
        workers: Sequence[str],
        liars: Iterable[str] = (),
        boasters: Iterable[str] = (),
        log_dir: Path | None = None,
        saboteurs: Iterable[str] = (),
        failers: Iterable[str] = (),
    ):
        self.workers = list(workers)
        self.liars = set(liars)
        self.boasters = set(boasters)
        self.saboteurs = set(saboteurs)
        self.failers = set(failers)
        self.log_dir = log_dir
        self.fetched: list[str] = []
        self.distrusted: set[str] = set()
        self.ran: dict[str, str] = {}  # job id → worker
        self._pending: dict[str, tuple[EpisodeSpec, tuple[str, ...]]] = {}
        self._turn = 0

    @property
    def capacity(self) -> int:
        return len(self.workers)

    def submit(
        self, specs: Mapping[str, EpisodeSpec], avoid: Mapping[str, Sequence[str]] | None = None
    ) -> None:
        for job_id, spec in specs.items():
            self._pending[job_id] = (spec, tuple((avoid or {}).get(job_id, ())))

    def distrust(self, worker: str) -> None:
        self.distrusted.add(worker)

    def cancel(self, job_ids: Iterable[str]) -> None:
        for job_id in job_ids:
            self._pending.pop(job_id, None)

    def results(self, timeout: float | None = None) -> Iterator[EpisodeResult]:
        """Every job some worker may run; a job every worker avoids waits (for ever: the
        timeout passes at once)."""
        while runnable := [job_id for job_id in self._pending if self._allowed(job_id)]:
            job_id = runnable[0]
            spec, avoid = self._pending.pop(job_id)
            yield self._run(job_id, spec, avoid)

    def fetch(
        self, wanted: Mapping[str, Wanted], simulate_again: bool = True
    ) -> dict[str, Fetched]:
        """Every log is had (the toy's workers keep them all), so `simulate_again` changes
        nothing."""
        fetched = {}
        for job_id, want in wanted.items():
            self.fetched.append(job_id)
            if self.log_dir is None:
                fetched[job_id] = Fetched(None, None, None, "the toy farm keeps no logs")
                continue
            self.log_dir.mkdir(parents=True, exist_ok=True)
            path = self.log_dir / f"{job_id}.mcap"
            log = want.spec.model_dump_json().encode()
            if want.holders[0] in self.liars:  # it serves the log it made
                log += b" (altered)"
            path.write_bytes(log)
            digest = hashlib.sha256(log).hexdigest()
            fetched[job_id] = Fetched(path, toy_scores(want.spec), digest, source=want.holders[0])
        return fetched

    def _allowed(self, job_id: str) -> list[str]:
        avoid = self._pending[job_id][1] if job_id in self._pending else ()
        return [w for w in self.workers if w not in avoid and w not in self.distrusted]

    def _run(self, job_id: str, spec: EpisodeSpec, avoid: tuple[str, ...]) -> EpisodeResult:
        allowed = [w for w in self.workers if w not in avoid and w not in self.distrusted]
        worker = allowed[self._turn % len(allowed)]
        self._turn += 1
        self.ran[job_id] = worker
        scores = toy_scores(spec)
        log = spec.model_dump_json().encode()
        if worker in self.liars:
            scores = scores.model_copy(update={"f_acc": scores.f_acc * 0.5})
            log += b" (altered)"
        if worker in self.boasters:
            scores = scores.model_copy(update={"f_acc": scores.f_acc * 0.5})
        if worker in self.saboteurs:
            scores = scores.model_copy(update={"f_acc": scores.f_acc * 5, "f_t": scores.f_t * 5})
        if worker in self.failers:
            return claimed_failure(job_id, spec, worker)
        return EpisodeResult(
            job_id=job_id,
            spec=spec,
            status=EpisodeStatus.ok,
            scores=scores,
            log=None,
            reason="",
            worker=worker,
            attempts=1,
            timings=None,
            digest=hashlib.sha256(log).hexdigest(),
        )


def run(tmp_path: Path, name: str, farm: ToyFarm, config: RunConfig = CONFIG) -> TuningRun:
    tuning = TuningRun.create(tmp_path / name, config)
    tuning.run(farm, referee=ToyFarm(["referee"]))
    return tuning


def front(tuning: TuningRun) -> list[tuple[float, float]]:
    return [member.objectives for member in tuning.front()]


def false_members(tuning: TuningRun) -> list[tuple[float, float]]:
    """Front members whose objectives are not what their gains truly score."""
    false = []
    for member in tuning.front():
        spec = EpisodeSpec(gains=member.gains, trajectory=tuning.config.trajectories[0])
        truth = toy_scores(spec)
        if member.objectives != (truth.f_acc, truth.f_t):
            false.append(member.objectives)
    return false


@pytest.mark.parametrize(
    "workers", [["h1", "liar", "h2", "h3"], ["h1", "liar"]], ids=["one-of-four", "one-of-two"]
)
def test_a_liar_is_caught_named_and_kept_out_of_the_front(
    tmp_path: Path, workers: list[str]
) -> None:
    lied_to = ToyFarm(workers, liars=["liar"])
    checked = run(tmp_path, "checked", lied_to)
    assert front(checked) and false_members(checked) == []
    # The points told, as evaluated.csv keeps them, carry the corrections too: the front is
    # their non-dominated set.
    told = read_evaluated(checked.directory / "evaluated.csv")
    assert set(front(checked)) == set(non_dominated(told))
    assert set(front(checked)) <= set(told)
    # The last history row says what the run reports: the validated front's hypervolume.
    last = checked.state.history[-1]
    assert last.hypervolume == hypervolume(front(checked), checked.config.reference_point)
    assert last.best_f_acc == min(f_acc for f_acc, _ in front(checked))
    assert set(checked.replication.dissenters) == {"liar"} == lied_to.distrusted
    assert checked.replication.disagreements >= 1 and checked.replication.unsettled == 0
    # Validation costs the front entrants' episodes again, not every evaluation.
    evaluations = checked.state.evolution.evaluations
    assert 0 < checked.replication.refereed < evaluations
    # Without validation, the liar's flattering scores reach the front.
    unchecked = run(
        tmp_path,
        "unchecked",
        ToyFarm(workers, liars=["liar"]),
        CONFIG.model_copy(update={"replicate": False}),
    )
    assert false_members(unchecked) != []


def test_colluding_liars_cannot_outvote_the_referee(tmp_path: Path) -> None:
    """Two liars make the same false log, so they agree with each other: a vote of workers
    would take it; the referee does not."""
    farm = ToyFarm(["liar1", "h1", "liar2"], liars=["liar1", "liar2"])
    front_only = CONFIG.model_copy(update={"spot_checks": 0.0})
    checked = run(tmp_path, "checked", farm, front_only)
    assert front(checked) and false_members(checked) == []
    assert set(checked.replication.dissenters) == {"liar1", "liar2"} == farm.distrusted
    # Started again without their results, the run retraced the honest farm's.
    assert checked.state.rewinds >= 1
    assert front(checked) == front(run(tmp_path, "honest", ToyFarm(["h1"]), front_only))


def test_an_honest_farm_validates_without_changing_the_front(tmp_path: Path) -> None:
    plain = run(
        tmp_path, "plain", ToyFarm(["h1", "h2"]), CONFIG.model_copy(update={"replicate": False})
    )
    checked = run(tmp_path, "checked", ToyFarm(["h1", "h2"]))
    assert front(checked) == front(plain)
    assert checked.replication.disagreements == 0 and not checked.replication.dissenters
    assert checked.replication.refereed > 0 and checked.replication.unsettled == 0


def test_an_episode_the_referee_cannot_run_is_unsettled_never_validated(tmp_path: Path) -> None:
    farm = ToyFarm(["h1", "h2"])
    farm.submit({"j": EpisodeSpec(gains=DEFAULT_GAINS)})
    [original] = list(farm.results())
    nobody = ToyFarm([])  # a referee that runs nothing (as one lacking the job's plug-in)
    ledger = Ledger()
    validation = validate(farm, [original], ledger, referee=nobody)
    assert validation.standing == {} and validation.unsettled == {"j"}
    assert ledger.unsettled == 1 and ledger.refereed == 0 and not ledger.dissenters
    assert nobody._pending == {}  # the referee is left with nothing queued


def test_a_worker_claiming_better_scores_than_its_honest_logs_is_caught_where_they_are_read(
    tmp_path: Path,
) -> None:
    # Replication votes on the logs, which are honest: only scoring the fetched logs again
    # catches the claims. Every front member's logs are fetched, so no false claim stays in it.
    farm = ToyFarm(
        ["h1", "boaster", "h2"], boasters=["boaster"], log_dir=tmp_path / "run" / "episodes"
    )
    tuning = run(tmp_path, "run", farm)
    assert farm.distrusted == {"boaster"} and farm.fetched
    assert front(tuning) and false_members(tuning) == []
    told = read_evaluated(tuning.directory / "evaluated.csv")
    assert set(front(tuning)) == set(non_dominated(told))
    for member in tuning.front():
        assert member.logs and all((tuning.directory / log).exists() for log in member.logs)


def test_without_logs_to_fetch_a_run_keeps_what_it_was_told(tmp_path: Path) -> None:
    farm = ToyFarm(["h1", "h2"])
    tuning = run(tmp_path, "run", farm)
    assert farm.fetched and not farm.distrusted and false_members(tuning) == []
    assert all(member.logs == () for member in tuning.front())


def test_a_front_member_keeps_the_standing_log_when_its_first_was_a_liars(tmp_path: Path) -> None:
    # The liar's log, fetched when its candidate entered the front, is outvoted by validation:
    # it goes, and the majority's is fetched from a worker that made it.
    farm = ToyFarm(["h1", "liar", "h2"], liars=["liar"], log_dir=tmp_path / "run" / "episodes")
    tuning = run(tmp_path, "run", farm)
    assert "liar" in farm.distrusted and false_members(tuning) == []
    for member in tuning.front():
        ran = {r.job_id: r for r in tuning.state.provenance[member.gains]}
        assert member.logs
        for log in member.logs:
            job_id = Path(log).stem
            content = (tuning.directory / log).read_bytes()
            assert hashlib.sha256(content).hexdigest() == ran[job_id].digest
            assert not content.endswith(b"(altered)")


@pytest.mark.parametrize("spot_checks", [0.0, 0.05])
@pytest.mark.parametrize("workers", [["h1", "liar", "h2", "h3"], ["h1", "liar"]])
def test_a_run_that_caught_a_liar_retraces_the_honest_farms_run(
    tmp_path: Path, workers: list[str], spot_checks: float
) -> None:
    config = CONFIG.model_copy(update={"spot_checks": spot_checks})
    honest = run(tmp_path, "honest", ToyFarm(["h1", "h2"]), config)
    farm = ToyFarm(workers, liars=["liar"])
    checked = run(tmp_path, "checked", farm, config)
    assert "liar" in checked.replication.dissenters
    # Caught on the front, it had steered the run: started again. (A spot check that caught
    # it on its first episode left nothing to start again for: the referee's run stands.)
    assert checked.state.rewinds >= 1 or spot_checks
    assert front(checked) == front(honest)
    assert checked.state.evaluated == honest.state.evaluated  # every point told, in order
    assert [row.hypervolume for row in checked.state.history] == [
        row.hypervolume for row in honest.state.history
    ]
    # What ran before the rewind was taken as it was, not run again: at most the evaluations
    # the lies had steered (a candidate of a generation told a lie) ran in vain.
    assert len(farm.ran) <= checked.state.evolution.evaluations * (1 + checked.state.rewinds)
    assert all(ran.worker != "liar" for runs in checked.state.provenance.values() for ran in runs)


def test_a_saboteur_whose_lies_never_reach_the_front_is_caught_by_spot_checks(
    tmp_path: Path,
) -> None:
    # Claims five times worse than it ran: its candidates lose, so no front check sees them.
    config = CONFIG.model_copy(update={"spot_checks": 0.5})
    honest = run(tmp_path, "honest", ToyFarm(["h1", "h2"]), config)
    farm = ToyFarm(["h1", "saboteur"], saboteurs=["saboteur"])
    checked = run(tmp_path, "checked", farm, config)
    # ~16 of its episodes, each drawn at 0.5: missed with probability 2^-16.
    assert set(checked.replication.dissenters) == {"saboteur"} == farm.distrusted
    assert "scores its log does not have" in checked.replication.dissenters["saboteur"]
    assert checked.replication.spot_checked > 0
    assert front(checked) == front(honest)
    # Without spot checks the front validation alone never sees it, and the run is steered.
    unchecked = run(
        tmp_path,
        "unchecked",
        ToyFarm(["h1", "saboteur"], saboteurs=["saboteur"]),
        CONFIG.model_copy(update={"spot_checks": 0.0}),
    )
    assert not unchecked.replication.dissenters and front(unchecked) != front(honest)


def test_spot_checks_draw_the_chosen_share_unpredictably_and_reproducibly() -> None:
    from gainfarm.analytic.evaluators.replication import spot_checked

    job_ids = [f"g{g:04d}-c{c:03d}-t0" for g in range(100) for c in range(100)]
    drawn = [job for job in job_ids if spot_checked(b"key", job, 0.05)]
    assert 0.04 < len(drawn) / len(job_ids) < 0.06
    assert drawn == [job for job in job_ids if spot_checked(b"key", job, 0.05)]
    other = [job for job in job_ids if spot_checked(b"another key", job, 0.05)]
    assert len(set(drawn) & set(other)) < len(drawn) / 5  # another key, another draw
    assert not any(spot_checked(b"key", job, 0.0) for job in job_ids)
    assert all(spot_checked(b"key", job, 1.0) for job in job_ids)


def test_the_records_say_who_ran_each_front_episode_and_how_it_was_checked(
    tmp_path: Path,
) -> None:
    import csv
    import json

    from gainfarm.analytic.tuning.records import read_front_json, read_validation
    from gainfarm.analytic.view.run_report import write_run_report

    farm = ToyFarm(["h1", "liar", "h2"], liars=["liar"])
    checked = run(tmp_path, "checked", farm, CONFIG.model_copy(update={"spot_checks": 0.0}))
    write_run_report(checked)
    directory = checked.directory
    validation = read_validation(directory / "front.json")
    assert validation is not None and validation == checked.validation()
    assert list(validation.distrusted) == ["liar"] and "referee" in validation.distrusted["liar"]
    assert validation.refereed > 0 and validation.rewinds >= 1 and not validation.unchecked
    members = read_front_json(directory / "front.json")
    assert [m.objectives for m in members] == front(checked)
    for member in members:
        [episode] = member.episodes  # one trajectory
        assert episode.worker in {"h1", "h2"} and episode.check in {"refereed", "spot-checked"}
        assert episode.ruling == "agreed"
    with (directory / "provenance.csv").open() as file:
        rows = list(csv.DictReader(file))
    assert [row["member"] for row in rows] == [str(i) for i in range(1, len(members) + 1)]
    assert {row["job_id"] for row in rows} == {m.episodes[0].job_id for m in members}
    report = (directory / "report.md").read_text()
    assert "## Validation" in report and "- distrusted: liar, which returned a log" in report
    assert "started again 1 time " in report or "started again 2 times " in report
    # A run in this process is trusted: nothing checked, and the records say why.
    from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator

    alone = TuningRun.create(tmp_path / "alone", RunConfig(pop=8, generations=1, seed=3))
    alone.run(InProcessEvaluator(alone.directory))
    content = json.loads((alone.directory / "front.json").read_bytes())
    assert content["validation"]["unchecked"].startswith("trusted")
    assert {e["check"] for m in content["members"] for e in m["episodes"]} == {"not checked"}


def test_a_liar_alone_is_corrected_or_stops_the_run_with_no_false_row(tmp_path: Path) -> None:
    # Caught on its front only: nobody is left to run its episodes again, so the referee's
    # runs of the front are all the correction there is.
    front_only = CONFIG.model_copy(update={"spot_checks": 0.0})
    checked = run(tmp_path, "front", ToyFarm(["liar"], liars=["liar"]), front_only)
    assert checked.state.stopped == "4 generations" and checked.state.rewinds == 0
    assert front(checked) and false_members(checked) == []
    assert set(checked.replication.dissenters) == {"liar"}
    # Caught on its first episode: the run stops there and says why.
    every = CONFIG.model_copy(update={"spot_checks": 1.0})
    stopped = run(tmp_path, "every", ToyFarm(["liar"], liars=["liar"]), every)
    assert stopped.state.stopped == "no trusted worker left (liar lied)"
    assert stopped.front() == [] and stopped.replication.spot_checked == 1
    from gainfarm.analytic.view.run_report import write_run_report

    write_run_report(stopped)  # a report that says so, with nothing to report
    report = (stopped.directory / "report.md").read_text()
    assert "no trusted worker left (liar lied)" in report and "- distrusted: liar" in report


def test_a_steady_state_run_distrusts_a_liar_and_reports_no_false_row(tmp_path: Path) -> None:
    # Its order is the farm's, so it is not replayed: the liar gets no more jobs, and the
    # front is refereed before it is reported.
    config = RunConfig(pop=8, evaluations=32, seed=3, asynchronous=True, spot_checks=0.5)
    farm = ToyFarm(["h1", "liar"], liars=["liar"])
    checked = run(tmp_path, "async", farm, config)
    assert checked.state.rewinds == 0 and set(checked.replication.dissenters) == {"liar"}
    assert front(checked) and false_members(checked) == []
    # Spot-checked as it returned: from then on the liar ran nothing (its ~16 episodes, each
    # drawn at 0.5: never drawn with probability 2^-16).
    checks = checked.state.checks
    caught = min(
        number
        for number, job in enumerate(farm.ran)
        if checks.get(job, ("", ""))[:2] == ("spot-checked", "contradicted")
    )
    assert all(worker == "h1" for worker in list(farm.ran.values())[caught + 1 :])


def test_a_failure_a_worker_claims_is_refereed_and_a_false_one_names_it(tmp_path: Path) -> None:
    front_only = CONFIG.model_copy(update={"spot_checks": 0.0})
    farm = ToyFarm(["h1", "failer"], failers=["failer"])
    checked = run(tmp_path, "checked", farm, front_only)
    ledger = checked.replication
    assert ledger.failures_checked >= 1 and ledger.disagreements >= 1
    assert "that the referee ran to scores" in ledger.dissenters["failer"]
    # Every episode it ran was a failure, each refereed and replaced: nothing of it is left to
    # start again without, and no candidate took the failure penalty.
    assert farm.distrusted == {"failer"}
    assert front(checked) == front(run(tmp_path, "honest", ToyFarm(["h1"]), front_only))
    validation = read_validation(checked.directory / "front.json")
    assert validation is not None and validation.failures_checked == ledger.failures_checked


def test_a_failure_is_taken_as_told_where_nothing_is_refereed(tmp_path: Path) -> None:
    # The contrast: unrefereed, the same farm's failures sink candidates (the penalty).
    unchecked = CONFIG.model_copy(update={"replicate": False})
    told = run(tmp_path, "told", ToyFarm(["h1", "failer"], failers=["failer"]), unchecked)
    honest = run(tmp_path, "honest", ToyFarm(["h1"]), unchecked)
    assert front(told) != front(honest)


def test_the_sized_spot_check_rate_is_fixed_as_the_run_starts_and_kept_on_resume(
    tmp_path: Path,
) -> None:
    sized = CONFIG.model_copy(update={"spot_checks": None})
    tuning = TuningRun.create(tmp_path / "run", sized)

    def stop(progress: RunProgress) -> None:
        if progress.ended:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        tuning.run(ToyFarm(["h1", "h2"]), stop, referee=ToyFarm(["referee"]))
    tuning.close()
    planned = 8 * 4  # pop x generations x one trajectory on one plant
    with TuningRun.open(tmp_path / "run") as resumed:
        assert resumed.state.spot_plan == (planned, 2)
        assert resumed.state.spot_rate == sized_rate(planned / 2)
        # Resumed on a farm of four, it draws as it would have: the rate of the start.
        resumed.run(ToyFarm(["h1", "h2", "h3", "h4"]), referee=ToyFarm(["referee"]))
        assert resumed.state.spot_rate == sized_rate(planned / 2)
    validation = read_validation(tmp_path / "run" / "front.json")
    assert validation is not None and validation.spot_check_rate == sized_rate(planned / 2)
    assert validation.spot_check_guarantee == (
        "sized: a worker lying on 10% of its share of the run's episodes (16: 32 planned over 2 "
        "workers) is caught with probability 0.99"
    )


@pytest.mark.parametrize(
    ("rate", "says"),
    [
        (0.0, "spot checks off (--spot-checks 0): only the front and failures are refereed"),
        (
            0.05,
            "set by hand: a worker lying on 10% of its share of the run's episodes (16: 32 "
            "planned over 2 workers) is caught with probability 0.0788",
        ),
    ],
)
def test_a_rate_set_by_hand_says_what_it_buys(tmp_path: Path, rate: float, says: str) -> None:
    tuning = run(
        tmp_path, "run", ToyFarm(["h1", "h2"]), CONFIG.model_copy(update={"spot_checks": rate})
    )
    assert tuning.state.spot_rate == rate
    assert tuning.validation().spot_check_guarantee == says
