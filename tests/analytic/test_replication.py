"""Validation by replication on a real farm: an honest farm agrees with itself, and a worker that
changes one torque sample of its logs is outvoted, named and given no more jobs."""

import hashlib
import subprocess
import sys
from pathlib import Path

import pytest

from analytic.farm import FarmClient
from analytic.local import spawn_worker, stop_workers
from analytic.replication import Ledger, validate
from broker.service import Broker
from tests.helpers import short_spec, wait_for

SPECS = {f"c{i}": short_spec(duration=0.4 + 0.1 * i) for i in range(3)}


def spawn_liar(endpoint: str, name: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "tests.analytic.liar", endpoint, name], stdin=subprocess.DEVNULL
    )


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def workers(broker: Broker, request: pytest.FixtureRequest):
    names: list[str] = request.param
    processes = [
        spawn_liar(broker.endpoints[0], name)
        if name.startswith("liar")
        else spawn_worker(broker.endpoints[0], name)
        for name in names
    ]
    wait_for(lambda: len(broker.status().workers) == len(names), what="the workers")
    yield names
    stop_workers(processes)


@pytest.mark.parametrize("workers", [["h1", "h2"]], indirect=True)
def test_an_honest_farm_agrees_with_itself(broker: Broker, workers, tmp_path: Path) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path) as farm:
        farm.submit(SPECS)
        originals = list(farm.results(60))
        ledger = Ledger()
        validation = validate(farm, originals, ledger)
    assert ledger.replicated == ledger.extra_evaluations == len(SPECS)
    assert ledger.disagreements == 0 and not ledger.dissenters and not validation.others
    assert validation.standing == {e.job_id: e for e in originals}
    assert sorted(p.name for p in (tmp_path / "episodes").iterdir()) == [
        f"{job_id}.mcap" for job_id in sorted(SPECS)
    ]  # the replicas' logs, once compared, are not kept


@pytest.mark.parametrize("workers", [["liar", "h1", "h2"]], indirect=True)
def test_a_worker_that_alters_one_torque_sample_is_outvoted_and_named(
    broker: Broker, workers, tmp_path: Path
) -> None:
    with FarmClient(broker.endpoints, "s", tmp_path) as farm:
        # Every original goes to the liar; its logs are valid and score almost the same.
        farm.submit(SPECS, avoid={job_id: ["h1", "h2"] for job_id in SPECS})
        originals = list(farm.results(60))
        assert {e.worker for e in originals} == {"liar"}
        ledger = Ledger()
        validation = validate(farm, originals, ledger)
        assert ledger.dissenters == {"liar"} and ledger.disagreements == len(SPECS)
        assert ledger.extra_evaluations == 2 * len(SPECS) and ledger.undecided == 0
        for job_id, original in ((e.job_id, e) for e in originals):
            standing = validation.standing[job_id]
            assert standing.worker in {"h1", "h2"} and standing.job_id == job_id
            assert standing.scores != original.scores
            assert standing.log == original.log and sha256(standing.log) == standing.digest
        # Distrusted: the liar gets none of the study's later jobs.
        farm.submit({"later": short_spec()})
        [later] = list(farm.results(60))
        assert later.worker in {"h1", "h2"}
