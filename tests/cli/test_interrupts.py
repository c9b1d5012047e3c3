"""Ctrl-C at any moment of a command line (cli/interrupts.py): exit status 130, one line on
stderr, never a traceback; real processes, real signals."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

IMPORT_TIME = "import time:"  # -X importtime's lines on stderr


def started(command: list[str], **options: object) -> subprocess.Popen[str]:
    """`python -X importtime -m gainfarm.PROGRAM ARGUMENTS`, once its interpreter is up (the
    `site` module imported): the moments count from there. Before that, Python itself cannot
    take Ctrl-C gracefully (a KeyboardInterrupt while it imports `site` is a fatal error in
    CPython), and on a loaded machine its start alone can take longer than the earliest
    moment."""
    running = subprocess.Popen(
        [sys.executable, "-X", "importtime", "-m", f"gainfarm.{command[0]}", *command[1:]],
        stderr=subprocess.PIPE,
        text=True,
        **options,  # type: ignore[call-overload]
    )
    assert running.stderr is not None
    for line in running.stderr:
        if line.startswith(IMPORT_TIME) and line.rstrip().endswith("| site"):
            return running
    raise AssertionError(f"{command[0]} ended before its interpreter was up")


def said(err: str) -> list[str]:
    """stderr's lines, -X importtime's left out."""
    return [line for line in err.splitlines() if not line.startswith(IMPORT_TIME)]


START = [
    *("start", "--pop", "4", "--generations", "3", "--trajectory", "fourier"),
    *("--duration", "0.5", "--out", "run"),
]


@pytest.mark.parametrize("delay", [0.1, 0.2, 0.35, 0.5, 0.75, 1.0, 1.25, 1.5, 2.5])
@pytest.mark.slow
def test_ctrl_c_early_in_a_start_is_one_line_and_status_130(tmp_path: Path, delay: float) -> None:
    """During the imports (the command's own, MuJoCo, Zenoh, pymoo), the local farm's start and
    the first generation."""
    running = started(["analytic", *START], cwd=tmp_path, stdout=subprocess.PIPE)
    time.sleep(delay)
    running.send_signal(signal.SIGINT)
    _, err = running.communicate(timeout=120)
    assert running.returncode == 130, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    lines = said(err)
    assert len(lines) == 1, err
    if lines[0] == "analytic: interrupted":  # nothing ran: nothing is left
        assert not (tmp_path / "run").exists()
    else:  # the run had begun (with its farm started first, early on): how to go on from it
        assert lines[0].startswith("analytic: stopped "), err
        assert lines[0].endswith(
            ("continue with: analytic resume run", "finish with: analytic resume run")
        ), err
        assert (tmp_path / "run").is_dir()


@pytest.mark.parametrize("program", ["worker", "broker"])
def test_ctrl_c_while_a_program_starts_is_one_line_and_status_130(program: str) -> None:
    running = started([program, "--version"], stdout=subprocess.PIPE)
    time.sleep(0.15)
    running.send_signal(signal.SIGINT)
    out, err = running.communicate(timeout=60)
    if running.returncode == 0:  # it was done before the signal came
        assert out.startswith(program) and said(err) == []
        return
    assert running.returncode == 130 and said(err) == [f"{program}: interrupted"], err


@pytest.mark.slow
def test_a_command_started_deaf_to_ctrl_c_stays_so(tmp_path: Path) -> None:
    """As a shell starts a background job (`analytic start ... &` in a script): an ignored
    SIGINT is left ignored, as Python itself leaves it, and the run goes on to its end."""
    running = subprocess.Popen(
        [sys.executable, "-m", "gainfarm.analytic", *START],
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    for _ in range(5):
        time.sleep(0.5)
        running.send_signal(signal.SIGINT)
    _, err = running.communicate(timeout=120)
    assert running.returncode == 0, err
    lines = err.splitlines()
    assert lines[lines.index("stopped after 3 generations") + 1].startswith("front, history"), err
