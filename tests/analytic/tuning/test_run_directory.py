"""A run directory nobody can break: unique study names, a checkpoint no stranger can abuse, one
writer at a time, no leftovers, and a full or read-only disk said in one line, then resumed.

Most tests run the toy problem in this process (milliseconds); the command-line ones run real
`analytic` processes, as a user (or an attacker) would.
"""

import contextlib
import hashlib
import importlib
import os
import pickle
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import types
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from numpy.testing._private.utils import runstring

from gainfarm.analytic.compose import new_study_name
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.tuning.checkpoint import ALLOWED, CheckpointRefused, _Unpickler
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import read_history, read_identity, read_run
from gainfarm.analytic.tuning.run import RunBusy, RunProgress, TuningRun, upgrade
from gainfarm.analytic.view.run_report import write_run_report
from gainfarm.edges.files import Lock
from gainfarm.schemas import TrajectorySpec
from gainfarm.schemas.wire import NAME_PATTERN
from tests.analytic.toy import toy_scores
from tests.helpers import analytic

TINY = RunConfig(
    pop=6, seed=7, trajectories=(TrajectorySpec(kind="fourier", duration=0.5),), generations=3
)


class Interrupt(Exception):
    pass


def stop_in(generation: int, pop: int) -> Callable[[RunProgress], None]:
    """A progress hook that stops the run within `generation`, as Ctrl-C would."""

    def hook(progress: RunProgress) -> None:
        if progress.generation == generation and progress.evaluations > generation * pop + 2:
            raise Interrupt

    return hook


def toy_run(directory: Path, config: RunConfig = TINY, stop: int | None = None) -> TuningRun:
    """A toy run, finished, or stopped halfway through generation `stop`; closed either way."""
    with TuningRun.create(directory, config) as run:
        if stop is None:
            run.run(InProcessEvaluator(scorer=toy_scores))
        else:
            with pytest.raises(Interrupt):
                run.run(InProcessEvaluator(scorer=toy_scores), stop_in(stop, config.pop))
    return run


def resume(directory: Path) -> TuningRun:
    with TuningRun.open(directory) as run:
        run.run(InProcessEvaluator(scorer=toy_scores))
    return run


def one_error_line(stderr: str) -> str:
    """The error of a command that failed: exactly one line of its own and no traceback (the
    workers of a local farm may log lines of theirs)."""
    assert "Traceback" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if line.startswith("analytic:")]
    assert len(lines) == 1 and lines[0].startswith("analytic: error: "), stderr
    return lines[0]


# --- study names ---------------------------------------------------------------------------


@pytest.mark.slow
def test_study_names_of_one_run_directory_differ_even_in_processes_of_one_pid(
    tmp_path: Path,
) -> None:
    names = [new_study_name(tmp_path / "run-1") for _ in range(100)]
    assert len(set(names)) == 100
    assert all(re.fullmatch(r"run-1-[0-9a-f]{8}", name) for name in names)
    # Two containers' `analytic` processes are both PID 1: the name owes nothing to the PID.
    code = (
        "import os; os.getpid = lambda: 1\n"
        "from pathlib import Path; from gainfarm.analytic.compose import new_study_name\n"
        "print(new_study_name(Path('runs/run-1')))"
    )
    made = [
        subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
        ).stdout.strip()
        for _ in range(2)
    ]
    assert made[0] != made[1] and all(name.startswith("run-1-") for name in made)


@pytest.mark.parametrize(
    "name", ["x" * 300, "my run (copy)", "ünïcode-ränge", "2024.05.01", "...", "--", "a/b"]
)
@pytest.mark.parametrize("owner", [None, "alice", "a" * 32])
def test_a_study_name_is_always_a_valid_key_chunk(
    tmp_path: Path, name: str, owner: str | None
) -> None:
    study = new_study_name(tmp_path / name, owner)
    assert re.fullmatch(NAME_PATTERN, study) and len(study) <= 64
    if owner is None:
        assert "." not in study
    else:  # the owner is everything before the first dot
        assert study.split(".", 1)[0] == owner


@pytest.mark.parametrize("owner", ["", "a.b", "a/b", "a" * 33, "ünï"])
def test_a_study_owner_is_a_participant_name(tmp_path: Path, owner: str) -> None:
    with pytest.raises(ValueError, match="study owner"):
        new_study_name(tmp_path / "run", owner)


# --- the checkpoint ------------------------------------------------------------------------


class Payload:
    """What a stranger's pickle does when it is loaded: call `function` with `arguments`."""

    def __init__(self, function: Callable[..., object], *arguments: object):
        self.function, self.arguments = function, arguments

    def __reduce__(self) -> tuple[Callable[..., object], tuple[object, ...]]:
        return self.function, self.arguments


def payloads(marker: Path) -> dict[str, object]:
    return {
        "os.system": Payload(os.system, f"touch {marker}"),
        "eval": Payload(eval, f"open({str(marker)!r}, 'w').close()"),
        "numpy.testing": Payload(runstring, f"open({str(marker)!r}, 'w').close()", {}),
    }


def header(run_id: str) -> bytes:
    return pickle.dumps({"format": "gainfarm checkpoint", "version": 2, "run_id": run_id})


@pytest.mark.parametrize("kind", ["os.system", "eval", "numpy.testing"])
@pytest.mark.parametrize("with_header", [False, True], ids=["bare", "behind-this-runs-header"])
def test_a_malicious_checkpoint_runs_no_code(tmp_path: Path, kind: str, with_header: bool) -> None:
    run = toy_run(tmp_path / "run", stop=2)
    marker = tmp_path / "pwned"
    evil = pickle.dumps(payloads(marker)[kind])
    if with_header:  # one who read run.json can forge the header: the state is still refused
        evil = header(run.identity.run_id) + evil
    (run.directory / "checkpoint.pkl").write_bytes(evil)
    with pytest.raises(CheckpointRefused, match="refusing") as refused:
        TuningRun.open(run.directory)
    assert "\n" not in str(refused.value)
    assert not marker.exists()


@pytest.mark.slow
def test_resume_of_a_malicious_checkpoint_is_one_line_and_runs_no_code(tmp_path: Path) -> None:
    run = toy_run(tmp_path / "run", stop=2)
    marker = tmp_path / "pwned"
    evil = pickle.dumps(Payload(os.system, f"touch {marker}"))
    for content in (evil, header(run.identity.run_id) + evil):
        (run.directory / "checkpoint.pkl").write_bytes(content)
        done = analytic("resume", "run", cwd=tmp_path)
        assert done.returncode == 2
        line = one_error_line(done.stderr)
        assert line.startswith("analytic: error: run/checkpoint.pkl: ") and "refusing" in line
        assert not marker.exists()


@pytest.mark.slow
def test_garbage_for_a_checkpoint_is_one_line(tmp_path: Path) -> None:
    run = toy_run(tmp_path / "run", stop=2)
    for content in (b"", b"not a pickle\n\x00", header(run.identity.run_id)):
        (run.directory / "checkpoint.pkl").write_bytes(content)
        with pytest.raises(CheckpointRefused, match="not a gainfarm checkpoint") as refused:
            TuningRun.open(run.directory)
        assert "\n" not in str(refused.value)
    done = analytic("resume", "run", cwd=tmp_path)
    assert done.returncode == 2
    assert "run/checkpoint.pkl: not a gainfarm checkpoint" in one_error_line(done.stderr)


@pytest.mark.slow
def test_a_checkpoint_of_another_run_is_refused_in_one_line(tmp_path: Path) -> None:
    # The same configuration: nothing but the run id tells the two apart.
    other = toy_run(tmp_path / "other")
    run = toy_run(tmp_path / "run", stop=2)
    shutil.copy(other.directory / "checkpoint.pkl", run.directory / "checkpoint.pkl")
    with pytest.raises(CheckpointRefused, match="another run"):
        TuningRun.open(run.directory)
    done = analytic("resume", "run", cwd=tmp_path)
    assert done.returncode == 2
    assert one_error_line(done.stderr) == (
        f"analytic: error: run/checkpoint.pkl: the checkpoint of another run (run id "
        f"{other.identity.run_id}), not of this one ({run.identity.run_id}): refusing to "
        "resume from it"
    )


def test_every_run_has_its_own_id_in_run_json_and_in_its_checkpoint(tmp_path: Path) -> None:
    one, two = toy_run(tmp_path / "one"), toy_run(tmp_path / "two")
    assert one.identity != two.identity
    assert read_identity(tmp_path / "one" / "run.json") == one.identity
    with open(tmp_path / "one" / "checkpoint.pkl", "rb") as stream:
        first = pickle.load(stream)  # the header: plain data, first
    assert first["run_id"] == one.identity.run_id


GENERATIONAL = {
    "default": TINY,
    "generic": TINY.model_copy(
        update={
            "trajectories": tuple(
                TrajectorySpec(kind="fourier", duration=0.5, seed=seed) for seed in range(3)
            )
        }
    ),
    "evaluations": TINY.model_copy(update={"generations": None, "evaluations": 20}),
    "converged": TINY.model_copy(update={"generations": None, "tolerance": 0.05, "window": 2}),
    "keep-front": TINY.model_copy(update={"keep": "front"}),
    "large": TINY.model_copy(update={"pop": 40, "seed": 3}),
}


@pytest.mark.parametrize("name", list(GENERATIONAL))
def test_every_kind_of_run_resumes_from_its_checkpoint_exactly(tmp_path: Path, name: str) -> None:
    """Every class these checkpoints hold is on the allowlist, and a resume still ends where an
    uninterrupted run does."""
    config = GENERATIONAL[name]
    whole = toy_run(tmp_path / "whole", config)
    toy_run(tmp_path / "stopped", config, stop=2)
    resumed = resume(tmp_path / "stopped")
    assert resumed.state.stopped == whole.state.stopped
    for file in ("front.csv", "evaluated.csv"):
        assert (tmp_path / "stopped" / file).read_bytes() == (
            tmp_path / "whole" / file
        ).read_bytes()


def test_a_steady_state_run_and_one_of_real_episodes_resume_through_the_allowlist(
    tmp_path: Path,
) -> None:
    steady = TINY.model_copy(update={"asynchronous": True, "generations": 4})
    toy_run(tmp_path / "steady", steady, stop=2)
    assert resume(tmp_path / "steady").state.stopped == "4 generations"
    real = RunConfig(
        pop=4, seed=1, trajectories=(TrajectorySpec(kind="fourier", duration=0.2),), generations=2
    )
    with TuningRun.create(tmp_path / "real", real) as run:
        run.run(InProcessEvaluator(tmp_path / "real"))  # timings, kept logs
    with TuningRun.open(tmp_path / "real") as reopened:
        assert reopened.state.busy_seconds == run.state.busy_seconds > 0
        assert reopened.front() == run.front() and reopened.front()[0].logs


def test_the_allowlist_names_no_whole_module() -> None:
    assert all(module and name and "*" not in name for module, name in ALLOWED)
    assert not any(module.startswith("numpy.testing") for module, _ in ALLOWED)
    assert not any(module in ("os", "posix", "builtins", "subprocess") for module, _ in ALLOWED)


def legacy_checkpoint(state: object) -> bytes:
    """A checkpoint as gainfarm wrote it before run ids: the state alone, every class named where
    it lived then (before the one import name `gainfarm`: analytic.run, schemas.gains, ...), its
    row types still in analytic.figures (as the earliest runs had them)."""
    with _named_as_before_the_move():
        content = pickle.dumps(state)
    assert b"gainfarm" not in content and b"analytic.figures" in content
    return content


@contextlib.contextmanager
def _named_as_before_the_move() -> Iterator[None]:
    """Each class and function a checkpoint holds is pickled under its old module path (as
    _Unpickler.MOVED lists them), through stand-in modules of those names."""
    olds: dict[str, str] = {}
    for (old, name), new in _Unpickler.MOVED.items():
        if name not in ("HistoryRow", "FrontMember") or old == "analytic.figures":
            olds[f"{new}:{name}"] = old
    renamed, added = [], []
    try:
        for where, old in olds.items():
            new, name = where.split(":")
            thing = getattr(importlib.import_module(new), name)
            renamed.append((thing, thing.__module__))
            thing.__module__ = old
            for depth in range(1, old.count(".") + 2):
                module = ".".join(old.split(".")[:depth])
                if module not in sys.modules:
                    sys.modules[module] = types.ModuleType(module)
                    added.append(module)
            setattr(sys.modules[old], name, thing)
        yield
    finally:
        for thing, module in renamed:
            thing.__module__ = module
        for module in added:
            del sys.modules[module]


def test_a_run_from_before_run_ids_gets_one_and_resumes_exactly(tmp_path: Path) -> None:
    whole = toy_run(tmp_path / "whole")
    old = tmp_path / "old"
    run = toy_run(old, stop=2)
    for name in ("run.json", "front.json", "evaluated.csv"):  # what the earliest runs lack
        (old / name).unlink()
    (old / "checkpoint.pkl").write_bytes(legacy_checkpoint(run.state))
    upgrade(old)
    assert read_run(old).history == run.state.history
    identity = read_identity(old / "run.json")
    pinned = hashlib.sha256((old / "checkpoint.pkl").read_bytes()).hexdigest()
    assert identity.legacy_checkpoint == pinned
    # Another id-less checkpoint is not the one the run was given its id with.
    (old / "checkpoint.pkl").write_bytes(legacy_checkpoint(whole.state))
    with pytest.raises(CheckpointRefused, match="without a run id"):
        TuningRun.open(old)
    (old / "checkpoint.pkl").write_bytes(legacy_checkpoint(run.state))
    resumed = resume(old)
    assert resumed.identity == identity
    assert (old / "front.csv").read_bytes() == (tmp_path / "whole" / "front.csv").read_bytes()
    with open(old / "checkpoint.pkl", "rb") as stream:
        first = pickle.load(stream)
    assert first["run_id"] == identity.run_id  # written anew, with the header


def test_reading_an_old_run_that_needs_no_upgrade_writes_nothing(tmp_path: Path) -> None:
    run = toy_run(tmp_path / "run")
    for name in ("run.json", "run.lock"):  # a finished run of before run ids, in an archive
        (run.directory / name).unlink()
    before = sorted(path.name for path in run.directory.iterdir())
    upgrade(run.directory)
    assert read_run(run.directory).stopped == "3 generations"
    assert sorted(path.name for path in run.directory.iterdir()) == before


def test_a_legacy_checkpoint_is_refused_by_a_run_that_never_had_one(tmp_path: Path) -> None:
    run = toy_run(tmp_path / "run", stop=2)
    (run.directory / "checkpoint.pkl").write_bytes(legacy_checkpoint(run.state))
    with pytest.raises(CheckpointRefused, match="without a run id"):
        TuningRun.open(run.directory)


# --- one writer at a time --------------------------------------------------------------------


def test_a_run_is_opened_by_one_writer_at_a_time(tmp_path: Path) -> None:
    run = toy_run(tmp_path / "run", stop=2)
    with TuningRun.open(run.directory), pytest.raises(RunBusy, match=f"process {os.getpid()} "):
        TuningRun.open(run.directory)
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    # A start that holds the lock but has not yet written config.json: a second waits its turn.
    with Lock(fresh / "run.lock"), pytest.raises(RunBusy):
        TuningRun.create(fresh, TINY)
    assert not (fresh / "config.json").exists()
    with TuningRun.open(run.directory) as again:  # released
        assert not again.finished
    with pytest.raises(RuntimeError, match="closed"):
        again.run(InProcessEvaluator(scorer=toy_scores))


def hold(directory: Path) -> subprocess.Popen[str]:
    """Another process holding the run open (so its lock), until it is killed."""
    code = (
        "import sys, time; from gainfarm.analytic.tuning.run import TuningRun\n"
        f"run = TuningRun.open({str(directory)!r}); print('open', flush=True); time.sleep(600)"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert holder.stdout is not None and holder.stdout.readline() == "open\n"
    return holder


def test_the_lock_dies_with_its_process_however_it_ends(tmp_path: Path) -> None:
    run = toy_run(tmp_path / "run", stop=2)
    holder = hold(run.directory)
    try:
        with pytest.raises(RunBusy, match=f"process {holder.pid} on {socket.gethostname()}"):
            TuningRun.open(run.directory)
    finally:
        holder.kill()
        holder.wait(10)
    assert holder.returncode == -signal.SIGKILL
    with TuningRun.open(run.directory) as reopened:  # no stale lock to clear
        assert not reopened.finished


@pytest.mark.slow
def test_resume_while_start_runs_is_refused_in_one_line_naming_the_process(
    tmp_path: Path,
) -> None:
    config = [
        "--pop",
        "4",
        "--generations",
        "50000",  # it must still be running when interrupted, however slow the machine
        "--trajectory",
        "fourier",
        "--duration",
        "0.5",
        "--out",
        "run",
    ]
    command = [sys.executable, "-m", "gainfarm.analytic", "start", *config]
    running = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    history = tmp_path / "run" / "history.csv"
    try:
        give_up = time.monotonic() + 120
        while not (history.exists() and len(read_history(history)) >= 1):
            assert time.monotonic() < give_up and running.poll() is None
            time.sleep(0.05)
        done = analytic("resume", "run", cwd=tmp_path)
        assert done.returncode == 2
        assert done.stderr == (
            f"analytic: error: 'run' is in use: process {running.pid} on "
            f"{socket.gethostname()} is running it (one start or resume of a run at a time)\n"
        )
        again = analytic("start", *config, cwd=tmp_path)
        assert again.returncode == 2 and "--out" in one_error_line(again.stderr)
    finally:
        running.send_signal(signal.SIGINT)
        try:
            _, err = running.communicate(timeout=60)
        finally:
            running.kill()  # never left running, whatever happened above
    assert running.returncode == 130, err
    generations = [row.generation for row in read_history(history)]
    assert generations == list(range(1, len(generations) + 1))  # never went backwards


# --- leftovers -------------------------------------------------------------------------------


@pytest.mark.slow
def test_leftovers_of_killed_writes_are_removed_at_resume_only_by_the_lock_holder(
    tmp_path: Path,
) -> None:
    run = toy_run(tmp_path / "run")
    with TuningRun.open(run.directory) as finished:  # drawn: a run with nothing left to do
        write_run_report(finished)
    (run.directory / "episodes").mkdir(exist_ok=True)
    leftovers = [
        run.directory / ".history.csv.k2j4h5g6.part",
        run.directory / ".checkpoint.pkl.a8b7c6d5.part",
        run.directory / "episodes" / ".g0001-c000-t0.mcap.q1w2e3r4.part",
    ]
    theirs = [run.directory / "notes.part", run.directory / ".keep", run.directory / "a.part.txt"]
    with TuningRun.open(run.directory):  # a writer holds the run: its writes are in progress
        for path in leftovers + theirs:
            path.write_bytes(b"half a file")
        with pytest.raises(RunBusy):
            TuningRun.open(run.directory)
        assert all(path.exists() for path in leftovers)
    done = analytic("resume", "run", cwd=tmp_path)  # opens the run, then finds it finished
    assert done.returncode == 2 and "has finished" in one_error_line(done.stderr)
    assert not any(path.exists() for path in leftovers)
    assert all(path.exists() for path in theirs)


# --- writes that fail ------------------------------------------------------------------------


def test_a_write_that_fails_stops_the_run_and_a_resume_goes_on_exactly(tmp_path: Path) -> None:
    """The rename of front.csv fails (a directory is in its way): the error names the file, no
    file is half-written, and the run resumes from its last good checkpoint."""
    whole = toy_run(tmp_path / "whole")
    directory = tmp_path / "run"

    def block_front_csv(progress: RunProgress) -> None:
        if progress.generation == 1 and (directory / "front.csv").is_file():
            (directory / "front.csv").unlink()
            (directory / "front.csv").mkdir()
            (directory / "front.csv" / "in-the-way").touch()

    with TuningRun.create(directory, TINY) as run, pytest.raises(OSError) as failed:
        run.run(InProcessEvaluator(scorer=toy_scores), block_front_csv)
    assert failed.value.filename == str(directory / "front.csv")
    assert not list(directory.rglob("*.part"))
    assert len(read_history(directory / "history.csv")) == 1
    with TuningRun.open(directory) as stopped:
        assert len(stopped.state.history) == 1
    shutil.rmtree(directory / "front.csv")
    resume(directory)
    for file in ("front.csv", "evaluated.csv"):
        assert (directory / file).read_bytes() == (whole.directory / file).read_bytes()


class Disk:
    """A small tmpfs of its own, to fill or make read-only for real (root only)."""

    def __init__(self, mount: Path):
        self.mount = mount

    def remount(self, options: str) -> None:
        """Remount with `options`; again if a write in progress keeps it busy a moment."""
        for _ in range(100):
            done = subprocess.run(
                ["mount", "-o", f"remount,{options}", str(self.mount)],
                capture_output=True,
                text=True,
                timeout=30,
            )
            if done.returncode == 0:
                return
            time.sleep(0.005)
        raise AssertionError(f"cannot remount {self.mount} {options}: {done.stderr}")


@pytest.fixture
def disk(tmp_path: Path) -> Iterator[Disk]:
    if os.geteuid() != 0:
        pytest.skip("a tmpfs to fill or make read-only needs root")
    mount = tmp_path / "disk"
    mount.mkdir()
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(mount)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    if made.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {made.stderr.strip()}")
    try:
        yield Disk(mount)
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True, timeout=30)


@pytest.mark.parametrize("fault", ["full", "read-only"])
@pytest.mark.slow
def test_a_full_or_read_only_disk_is_one_line_and_a_resume_goes_on(
    tmp_path: Path, disk: Disk, fault: str
) -> None:
    generations = 3 if fault == "full" else 6
    options = [
        "--pop",
        "4",
        "--trajectory",
        "fourier",
        "--duration",
        "0.5",
        "--generations",
        str(generations),
        *("--keep", "all"),  # every episode's log: the disk fills in the second generation
        *("--plants", "0"),  # one episode a candidate: the disk is sized for a generation's 4
    ]
    command = [sys.executable, "-m", "gainfarm.analytic", "start", *options, "--out", "disk/run"]
    directory = disk.mount / "run"
    if fault == "full":
        # Room for the first generation's logs (4 × ~175 kB, the robot's description included)
        # and records, not the second's.
        disk.remount("size=1000k")
    running = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    if fault == "read-only":
        history = directory / "history.csv"
        give_up = time.monotonic() + 120
        while not (history.exists() and read_history(history)):
            assert time.monotonic() < give_up and running.poll() is None
            time.sleep(0.01)
        disk.remount("ro")
    _, err = running.communicate(timeout=300)
    assert running.returncode == 2, err
    reason = "No space left on device" if fault == "full" else "Read-only file system"
    line = one_error_line(err)
    assert re.fullmatch(
        rf"analytic: error: cannot write 'disk/run/\S+': {reason}; once it can, "
        r"go on with: analytic resume disk/run",
        line,
    ), line
    assert not list(directory.rglob("*.part"))  # nothing half-written
    stopped = read_run(directory)
    assert 1 <= len(stopped.history) < generations and stopped.stopped is None
    calm = tmp_path / "calm"
    with TuningRun.create(calm, stopped.config) as run:
        run.run(InProcessEvaluator(calm))  # the farm's front, as test_run shows
    disk.remount("rw,size=64m")
    resumed = analytic("resume", "disk/run", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert f"stopped after {generations} generations" in resumed.stderr
    assert (directory / "front.csv").read_bytes() == (calm / "front.csv").read_bytes()
    history = read_history(directory / "history.csv")
    assert [row.generation for row in history] == list(range(1, generations + 1))
