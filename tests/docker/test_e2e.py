"""docker/e2e.py: its checks, on a run made here; and the script run for real, end to end.

The end-to-end test takes minutes, so it runs only with `-m e2e` (.ci/run runs it after the unit
tests). The script checks the farm's runs itself and tears everything down; the test runs it,
skips with its one line where no container engine can run, and reads the run directories it
kept with this checkout's own readers and with the mcap library: every front member's log, made
in a container, scores here as the front says.
"""

import importlib.util
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.reader import make_reader

from gainfarm.analytic import RunConfig, tune
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.tuning.defaults import PLANTS
from gainfarm.analytic.tuning.records import read_run
from gainfarm.analytic.view.members import episode, slots
from gainfarm.schemas import TrajectorySpec
from gainfarm.schemas.objectives import objectives, score

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "docker" / "e2e.py"
_spec = importlib.util.spec_from_file_location("docker_e2e", SCRIPT)
assert _spec is not None and _spec.loader is not None
e2e = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(e2e)

# --- the script's checks catch what they should ------------------------------------------------


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run of the size the script runs (real episodes, in this process): what it accepts."""
    out = tmp_path_factory.mktemp("e2e") / "tune"
    spiral = (TrajectorySpec(duration=3.0),)
    # Every episode's log, as an in-process evaluator writes them all (the check knows both).
    config = RunConfig(pop=e2e.POP, generations=e2e.GENERATIONS, trajectories=spiral, keep="all")
    assert f"--duration {spiral[0].duration:g}" in e2e.RUN_ARGS
    tune(config, out, evaluator=InProcessEvaluator(out))
    return out


def test_the_run_check_accepts_a_finished_run(finished_run: Path) -> None:
    e2e.check_run(finished_run, owner=os.getuid())


def _truncate_a_log(run: Path) -> None:
    log = next((run / "episodes").iterdir())
    log.write_bytes(log.read_bytes()[: log.stat().st_size // 2])


def _drop_a_member(run: Path) -> None:
    front = json.loads((run / "front.json").read_text())
    (run / "front.json").write_text(json.dumps({"members": front["members"][1:]}))


DAMAGE: dict[str, Callable[[Path], None]] = {
    "a log cut short": _truncate_a_log,
    "a log missing": lambda run: next((run / "episodes").iterdir()).unlink(),
    "a generation short": lambda run: (run / "history.csv").write_text(
        "".join((run / "history.csv").read_text().splitlines(keepends=True)[:-1])
    ),
    "no figure": lambda run: (run / "pareto.png").unlink(),
    "front.json short of front.csv": _drop_a_member,
    "another configuration": lambda run: (run / "config.json").write_text(
        (run / "config.json").read_text().replace(f'"pop": {e2e.POP}', '"pop": 30')
    ),
}


@pytest.mark.parametrize("damage", DAMAGE)
def test_the_run_check_rejects_a_damaged_run(
    finished_run: Path, tmp_path: Path, damage: str
) -> None:
    run = tmp_path / "tune"
    shutil.copytree(finished_run, run)
    DAMAGE[damage](run)
    with pytest.raises(e2e.Failure):
        e2e.check_run(run, owner=os.getuid())


def test_the_run_check_rejects_files_of_another_user(finished_run: Path) -> None:
    with pytest.raises(e2e.Failure, match="owned by"):
        e2e.check_run(finished_run, owner=os.getuid() + 1)


def test_every_worker_must_have_done_a_job_of_the_run() -> None:
    before = {"a": 3, "b": 0, "c": 1}
    e2e.check_every_worker_worked(before, {"a": 4, "b": 2, "c": 2})
    with pytest.raises(e2e.Failure, match=r"\['b'\]"):
        e2e.check_every_worker_worked(before, {"a": 9, "b": 0, "c": 2})
    with pytest.raises(e2e.Failure, match="changed"):
        e2e.check_every_worker_worked(before, {"a": 4, "b": 2, "d": 2})


def test_where_no_engine_can_run_it_says_why_in_one_line_and_exits_77() -> None:
    # Run as a user who may run no engine (nobody, when this is root). The script needs only the
    # standard library, so it runs from a copy that user can read, with the base interpreter.
    with tempfile.TemporaryDirectory() as scratch:
        Path(scratch).chmod(0o777)
        copy = Path(scratch) / "docker" / "e2e.py"
        copy.parent.mkdir()
        shutil.copy(SCRIPT, copy)
        command = [os.path.realpath(sys.executable), str(copy), "--state", f"{scratch}/state"]
        if os.geteuid() == 0:
            command = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", *command]
        done = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == e2e.SKIP, done.stdout + done.stderr
    assert done.stderr == ""
    (line,) = done.stdout.splitlines()
    assert re.fullmatch(r"e2e: skipped: needs root to (run a container engine|install .+)", line)


# --- the whole farm, for real ------------------------------------------------------------------


# Cold on the 2-core machine (engine, base image, wheels, build) it took 12 minutes under load.
TIMEOUT = 45 * 60
TEARDOWN = 5 * 60


@pytest.mark.e2e
def test_the_compose_farm_runs_its_tuning_profiles_for_real(tmp_path: Path) -> None:
    kept = tmp_path / "runs"
    script = subprocess.Popen(
        [sys.executable, str(SCRIPT), "--keep-runs", str(kept)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        output, _ = script.communicate(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        script.send_signal(signal.SIGTERM)  # it tears the farm and its daemon down first
        output, _ = script.communicate(timeout=TEARDOWN)
        pytest.fail(f"docker/e2e.py took over {TIMEOUT} s:\n{output}")
    print(output)  # its steps and how long each took: `pytest -rP` shows them on a pass
    lines = output.strip().splitlines() or [""]
    if script.returncode == e2e.SKIP:
        pytest.skip(lines[-1].removeprefix("e2e: skipped: "))
    assert script.returncode == 0, output

    runs = sorted(path.parent.relative_to(kept) for path in kept.rglob("run.json"))
    assert runs == sorted(Path(run) for run in ("tune", *e2e.TWINS, "secure"))
    run_ids = set()
    for run in runs:
        record = read_run(kept / run)
        assert record.evaluations == e2e.POP * e2e.GENERATIONS
        assert len(record.evaluated) == record.evaluations
        run_ids.add((kept / run / "run.json").read_text())
        assert record.front
        config = record.config
        plants = 1 + len(config.plants)  # analytic start's robust default: the nominal + corners
        assert plants == 1 + PLANTS
        for member in record.front:
            assert len(member.logs) == plants  # one trajectory, on each plant
            found = [episode(kept / run, config, member, slot) for slot in slots(config)]
            assert all(where.startswith("its log") for _, where in found), found
            scores = [score(log) for log, _ in found if log is not None]
            rescored = objectives(
                scores, config.objective_weights, plants, config.aggregate, config.plant_scales
            )
            assert rescored == member.objectives, f"{run}: {member.logs}"
            for log in member.logs:
                with (kept / run / log).open("rb") as file:
                    summary = make_reader(file).get_summary()
                assert summary is not None and summary.statistics is not None
                assert summary.statistics.message_count > 0 and summary.channels
    assert len(run_ids) == len(runs), "every run has an id of its own"
    # One seed and configuration: one front, byte for byte, on the plain farm, two runs at once
    # sharing it, and the secure farm (docs/tuning.md: Guarantees).
    fronts = {(kept / run / "front.csv").read_bytes() for run in runs}
    assert len(fronts) == 1
