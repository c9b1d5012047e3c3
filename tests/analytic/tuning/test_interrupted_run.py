"""Ctrl-C at each stage of `analytic start`, on a real local farm: what it says is what it left,
and `analytic resume` finishes what is left."""

import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from gainfarm.analytic.tuning.records import read_history
from gainfarm.analytic.tuning.run import TuningRun
from tests.helpers import analytic, ends_with_closing_lines

START = [sys.executable, "-m", "gainfarm.analytic", "start"]


def interrupt_at(command: list[str], cwd: Path, wanted: re.Pattern[str]) -> tuple[list[str], str]:
    """Run `command`, press Ctrl-C as soon as it prints a line matching `wanted`, and return
    the lines before that one, then the last line it printed (its own, on the way out)."""
    running = subprocess.Popen(command, cwd=cwd, stderr=subprocess.PIPE, text=True)
    seen: list[str] = []
    try:
        assert running.stderr is not None
        for line in running.stderr:
            if wanted.search(line):
                running.send_signal(signal.SIGINT)
                break
            seen.append(line.rstrip("\n"))
        else:
            raise AssertionError(f"it ended before a line matching {wanted.pattern!r}: {seen}")
        rest = running.stderr.read().splitlines()
        assert running.wait(timeout=60) == 130, rest
    finally:
        running.kill()
    assert not any("Traceback" in line for line in seen + rest), rest
    return seen, rest[-1]


@pytest.mark.slow
def test_ctrl_c_during_the_held_out_check_is_finished_by_a_resume(tmp_path: Path) -> None:
    # One worker, so that the check's episodes run one after another: seconds to stop it in.
    # The default 5 s spiral on the nominal plant and the two corners, which the default gains
    # (the first population's) keep the limits on: a front to check.
    options = ["--pop", "4", "--generations", "2", "--duration", "5", "--seed", "7"]
    farm = ["--local", "--workers", "1"]
    command = [*START, *options, "--plants", "2", *farm, "--out", "run"]
    seen, last = interrupt_at(command, tmp_path, re.compile(r"^held-out check: "))
    assert seen[-1].startswith("generation 2: ")
    assert last == (
        "analytic: stopped during the held-out check, after the evolution's 2 generations; "
        "finish with: analytic resume run"
    )
    run = tmp_path / "run"
    assert not (run / "check.json").exists() and not (run / "report.md").exists()
    assert len(read_history(run / "history.csv")) == 2

    resumed = analytic("resume", "run", *farm, cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    lines = resumed.stderr.splitlines()
    assert not any(line.startswith("generation ") for line in lines)  # the evolution was over
    check = json.loads((run / "check.json").read_text())
    assert check["asked"] == 64 and 1 <= check["plants"] < 64  # CHECK_SHARE's cap
    episodes = check["cost"]["episodes"]
    assert (
        f"held-out check: {episodes} episodes on {check['plants']} of the 64 held-out plants asked"
    ) in lines
    for name in ("report.md", "pareto.png", "hypervolume.png"):
        assert (run / name).exists(), name
    report = (run / "report.md").read_text()
    assert f"on {check['plants']} of the 64 held-out plants asked (the check may take" in report
    ends_with_closing_lines(lines, run)  # with the held-out lines of check.json's figures
    assert len(read_history(run / "history.csv")) == 2

    again = analytic("resume", "run", *farm, cwd=tmp_path)
    assert again.returncode == 2 and "has finished: 2 generations" in again.stderr


@pytest.mark.slow
def test_ctrl_c_names_the_generation_saved_and_resume_runs_on_from_it(tmp_path: Path) -> None:
    # Generations of 4 short episodes end every fraction of a second; the records are written
    # at the first and then at most every 10 s (RECORD_SECONDS), so at the third generation's
    # line only the first is saved.
    options = ["--pop", "4", "--generations", "12", "--trajectory", "fourier", "--duration", "0.5"]
    command = [*START, *options, "--check-plants", "0", "--out", "run"]
    _, last = interrupt_at(command, tmp_path, re.compile(r"^generation 3: "))
    said = re.fullmatch(
        r"analytic: stopped after (\d+) generations, saved at generation 1; continue with: "
        r"analytic resume run \(it runs generation 2 on\)",
        last,
    )
    assert said and int(said.group(1)) >= 3, last
    run = tmp_path / "run"
    assert [row.generation for row in read_history(run / "history.csv")] == [1]
    with TuningRun.open(run) as saved:
        assert len(saved.state.history) == 1 and not saved.finished

    resumed = analytic("resume", "run", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    generations = [line for line in resumed.stderr.splitlines() if line.startswith("generation ")]
    assert generations[0].startswith("generation 2: "), generations
    assert [row.generation for row in read_history(run / "history.csv")] == list(range(1, 13))


def children(pid: int) -> set[int]:
    """The processes `pid` started and has not reaped (its local farm's broker and workers)."""
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        found |= {int(child) for child in (task / "children").read_text().split()}
    return found


def alive(pid: int) -> bool:
    """Whether `pid` still runs (a zombie has ended: only its status is left to reap)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


@pytest.mark.slow
def test_sigterm_stops_a_start_as_ctrl_c_does_and_leaves_no_farm_behind(tmp_path: Path) -> None:
    options = ["--pop", "4", "--generations", "12", "--trajectory", "fourier", "--duration", "0.5"]
    command = [*START, *options, "--check-plants", "0", "--workers", "2", "--out", "run"]
    running = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    try:
        assert running.stderr is not None
        for line in running.stderr:
            if line.startswith("generation 2: "):
                break
        else:
            raise AssertionError("it ended before its second generation")
        farm = children(running.pid)
        assert len(farm) == 3  # the broker and two workers
        running.send_signal(signal.SIGTERM)
        rest = running.stderr.read().splitlines()
        assert running.wait(timeout=60) == 128 + signal.SIGTERM, rest
    finally:
        running.kill()
    assert not any("Traceback" in line for line in rest), rest
    assert re.fullmatch(
        r"analytic: stopped after \d+ generations, saved at generation 1; .*", rest[-1]
    ), rest
    # Stopped and reaped as the run stopped: none is left running, orphaned, to its init.
    assert not [pid for pid in farm if alive(pid)]
