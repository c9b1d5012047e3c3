"""Validation by a referee on a real farm: this process runs the episodes again, an honest
farm agrees with it, and a worker that changes one torque sample of its logs is caught, named and
given no more jobs, on a farm of two."""

import dataclasses
import hashlib
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.evaluator import EpisodeStatus, Wanted
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import spawn_worker, stop_workers
from gainfarm.analytic.evaluators.replication import (
    Check,
    Ledger,
    Ruling,
    caught_probability,
    sized_rate,
    validate,
)
from gainfarm.broker.service import Broker
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.service import CobotWorker
from tests.analytic.toy import claimed_failure
from tests.helpers import short_spec, wait_for

SPECS = {f"c{i}": short_spec(duration=0.4 + 0.1 * i) for i in range(3)}


def spawn_liar(endpoint: str, name: str) -> subprocess.Popen:
    """A liar ("liar…": alters its logs) or a boaster ("boaster…": claims better scores)."""
    how = ["--scores"] if name.startswith("boaster") else []
    return subprocess.Popen(
        [sys.executable, "-m", "tests.analytic.liar", endpoint, name, *how],
        stdin=subprocess.DEVNULL,
    )


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def workers(broker: Broker, request: pytest.FixtureRequest):
    names: list[str] = request.param
    processes = [
        spawn_liar(broker.endpoints[0], name)
        if name.startswith(("liar", "boaster"))
        else spawn_worker(broker.endpoints[0], name)
        for name in names
    ]
    # Worker processes import MuJoCo as they start: 30 s, as every spawned worker is given.
    wait_for(lambda: len(broker.status().workers) == len(names), 30, "the workers")
    yield names
    stop_workers(processes)


@pytest.mark.parametrize("workers", [["h1", "h2"]], indirect=True)
@pytest.mark.slow
def test_an_honest_farm_agrees_with_the_referee(broker: Broker, workers, tmp_path: Path) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path) as farm:
        farm.submit(SPECS)
        originals = list(farm.results(60))
        ledger = Ledger()
        validation = validate(farm, originals, ledger, referee=InProcessEvaluator(tmp_path))
    assert ledger.refereed == len(SPECS) and ledger.unsettled == 0
    assert ledger.disagreements == 0 and not ledger.dissenters and not validation.unsettled
    assert validation.standing == {e.job_id: e for e in originals}
    assert sorted(p.name for p in (tmp_path / "episodes").iterdir()) == [
        f"{job_id}.mcap" for job_id in sorted(SPECS)
    ]  # the referee's logs, once compared, are not kept


@pytest.mark.parametrize("workers", [["liar", "h1"]], indirect=True)
@pytest.mark.slow
def test_a_worker_that_alters_one_torque_sample_is_caught_and_named_on_a_farm_of_two(
    broker: Broker, workers, tmp_path: Path
) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path) as farm:
        # Every original goes to the liar; its logs are valid and score almost the same.
        farm.submit(SPECS, avoid={job_id: ["h1"] for job_id in SPECS})
        originals = list(farm.results(60))
        assert {e.worker for e in originals} == {"liar"}
        ledger = Ledger()
        validation = validate(farm, originals, ledger, referee=InProcessEvaluator(tmp_path))
        assert set(ledger.dissenters) == {"liar"} and ledger.disagreements == len(SPECS)
        assert ledger.refereed == len(SPECS) and ledger.unsettled == 0
        for job_id, original in ((e.job_id, e) for e in originals):
            standing = validation.standing[job_id]
            assert standing.worker == "in-process" and standing.job_id == job_id
            assert standing.scores != original.scores
            assert standing.log == original.log and sha256(standing.log) == standing.digest
            assert standing.scores == score(read_episode(standing.log))
        # Distrusted: the liar gets none of the study's later jobs.
        farm.submit({"later": short_spec()})
        [later] = list(farm.results(60))
        assert later.worker == "h1"
    assert not list((tmp_path / "episodes").glob("*-ref*"))


@pytest.mark.parametrize("workers", [["boaster", "h1"]], indirect=True)
@pytest.mark.slow
def test_scores_better_than_the_log_has_are_caught_where_the_log_is_read(
    broker: Broker, workers, tmp_path: Path
) -> None:
    boasted = {"b0": short_spec(duration=0.5)}
    # Logs sent with the results: read as they come, so the claim never counts.
    with FarmClient(broker.endpoints, "sent", tmp_path / "sent") as farm:
        farm.submit(boasted, avoid={"b0": ["h1"]})
        for _ in range(120):  # nothing counts, until the claim is caught (at most 60 s)
            assert list(farm.results(0.5)) == []
            if farm.distrusted:
                break
        assert farm.distrusted == {"boaster"}  # refused, then the boaster gets no more jobs
        farm.cancel(["b0"])  # no worker left to run it: h1 is avoided, the boaster distrusted
        farm.submit({"b1": short_spec(duration=0.5)})
        [later] = list(farm.results(60))
        assert later.worker == "h1" and later.scores == score(read_episode(later.log))
    # Logs kept by the workers: the claim counts until the log is fetched and read.
    with FarmClient(broker.endpoints, "kept", tmp_path / "kept", keep_logs=False) as farm:
        farm.submit(boasted, avoid={"b0": ["h1"]})
        [claimed] = list(farm.results(60))
        assert claimed.worker == "boaster" and claimed.log is None
        wanted = Wanted(claimed.spec, claimed.digest, ("boaster",))
        fetched = farm.fetch({"b0": wanted})["b0"]
    assert fetched.digest == claimed.digest and sha256(fetched.log) == claimed.digest
    truth = score(read_episode(fetched.log))
    assert fetched.scores == truth and claimed.scores != truth
    assert claimed.scores.f_acc == pytest.approx(0.9 * truth.f_acc)


@pytest.mark.parametrize("workers", [["h1", "h2"]], indirect=True)
@pytest.mark.slow
def test_a_log_is_fetched_from_its_worker_or_else_simulated_again(
    broker: Broker, workers, tmp_path: Path
) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path, keep_logs=False) as farm:
        farm.submit(SPECS)
        evaluations = {e.job_id: e for e in farm.results(60)}
        assert all(e.log is None and e.digest for e in evaluations.values())
        wanted = {
            job_id: Wanted(e.spec, e.digest, (e.worker,)) for job_id, e in evaluations.items()
        }
        wanted["c0"] = dataclasses.replace(wanted["c0"], holders=("nobody",))  # a holder gone
        # Not simulating again (a run's periodic records): the gone log is left, nothing runs.
        kept = farm.fetch(wanted, simulate_again=False)
        assert kept["c0"].log is None and kept["c0"].reason == "its holders have it no more"
        assert all(kept[j].digest == evaluations[j].digest for j in kept if j != "c0")
        assert not (tmp_path / "episodes" / "c0.mcap").exists()
        fetched = farm.fetch(wanted)
    for job_id, got in fetched.items():
        assert got.log == tmp_path / "episodes" / f"{job_id}.mcap"
        assert got.digest == evaluations[job_id].digest == sha256(got.log)
        assert got.scores == evaluations[job_id].scores == score(read_episode(got.log))
        assert got.source == evaluations[job_id].worker or job_id == "c0"
    assert fetched["c0"].source in {"h1", "h2"}  # whichever ran it again
    assert not list((tmp_path / "episodes").glob("*-k*"))  # the rerun's log took the job's name


@pytest.mark.slow
def test_a_log_run_again_is_fetched_from_the_worker_that_ran_it_or_the_fetch_fails(
    broker: Broker, tmp_path: Path
) -> None:
    """A client without keep_logs fetches no log with a result, reruns included: the rerun's log
    is fetched from the worker that ran it, and a worker that keeps no logs fails the fetch
    cleanly, with a reason."""
    with (
        CobotWorker(broker.endpoints, "forgetful", log_memory=0) as worker,
        FarmClient(broker.endpoints, "s", tmp_path, keep_logs=False) as farm,
    ):
        serving = threading.Thread(target=worker.serve, args=(threading.Event(), 2))
        serving.start()
        farm.submit({"j": short_spec()})
        [result] = list(farm.results(60))
        assert result.log is None and result.worker == "forgetful"
        wanted = Wanted(result.spec, result.digest, ("forgetful",))
        fetched = farm.fetch({"j": wanted})["j"]
        serving.join(60)
    assert not serving.is_alive() and worker.jobs_done == 2  # the job, then its rerun
    assert fetched.log is None and fetched.scores is None
    assert fetched.reason == "simulated again on forgetful, but its log was not had"
    assert not list((tmp_path / "episodes").glob("*.mcap"))


@pytest.mark.parametrize("episodes", [1, 12, 72, 144, 900, 10_000])
def test_the_sized_rate_catches_a_tenth_lied_on_with_probability_0_99(episodes: int) -> None:
    rate = sized_rate(episodes)
    assert 0 < rate <= 1
    assert rate == pytest.approx(1 - 0.01 ** (1 / (0.1 * episodes)))
    assert caught_probability(rate, episodes) >= 0.99 - 1e-12
    if rate < 1:  # the least rate that buys it: any lower buys less
        assert caught_probability(rate, episodes) == pytest.approx(0.99)
        assert caught_probability(rate * 0.95, episodes) < 0.99


def test_the_sized_rate_falls_as_a_worker_returns_more_episodes() -> None:
    rates = [sized_rate(n) for n in (12, 72, 144, 900)]
    assert rates == sorted(rates, reverse=True)
    # A 48-evaluation 3-plant run on 2 workers; a 600-evaluation one: about the former 5 %.
    assert round(sized_rate(48 * 3 / 2), 3) == 0.473 and round(sized_rate(600 * 3 / 2), 3) == 0.05
    assert sized_rate(0) == 1.0 and sized_rate(20) < sized_rate(10) < 1.0
    assert sized_rate(100, share=1.0, confidence=0.5) == pytest.approx(1 - 0.5 ** (1 / 100))


def test_caught_probability_at_the_edges() -> None:
    assert caught_probability(0.0, 100) == 0.0
    assert caught_probability(1.0, 100) == 1.0 and caught_probability(1.0, 0) == 0.0
    assert caught_probability(0.05, 600) == pytest.approx(1 - 0.95**60)


def test_a_failure_the_referee_runs_to_scores_names_its_worker(tmp_path: Path) -> None:
    ledger = Ledger()
    spec = SPECS["c0"]
    validation = validate(
        InProcessEvaluator(tmp_path / "farm"),
        [claimed_failure("c0", spec)],
        ledger,
        referee=InProcessEvaluator(tmp_path / "referee"),
        check=Check.failure_checked,
    )
    assert validation.rulings == {"c0": Ruling.contradicted}
    standing = validation.standing["c0"]
    assert standing.status == EpisodeStatus.ok and standing.log is not None
    assert standing.scores == score(read_episode(standing.log))
    assert ledger.dissenters == {"w1": "failed job c0 that the referee ran to scores"}
    assert ledger.failures_checked == 1 and ledger.disagreements == 1


def test_a_failure_the_referee_fails_too_stands_and_names_nobody(tmp_path: Path) -> None:
    ledger = Ledger()
    unreachable = SPECS["c0"].model_copy(
        update={"trajectory": TrajectorySpec(center=(1.5, 0.0, 0.4), duration=3.0)}
    )
    validation = validate(
        InProcessEvaluator(tmp_path / "farm"),
        [claimed_failure("c0", unreachable), claimed_failure("c1", SPECS["c1"], worker="")],
        ledger,
        referee=InProcessEvaluator(tmp_path / "referee"),
        check=Check.failure_checked,
    )
    # An honest failure stands; one this process made of a result it could not use (no
    # worker's word) is no claim to referee.
    assert validation.rulings == {"c0": Ruling.agreed}
    assert validation.standing["c0"].status == EpisodeStatus.failed
    assert ledger.dissenters == {} and ledger.failures_checked == 1 and ledger.disagreements == 0
