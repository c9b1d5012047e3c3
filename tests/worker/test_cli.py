"""The command lines, run as a user runs them: real subprocesses, real files."""

import json
import subprocess
import sys

import pytest

WORKER = [sys.executable, "-c", "from worker.cli import main; main()"]
ANALYTIC = [sys.executable, "-c", "from analytic.cli import main; main()"]


def run(command: list[str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*command, *args], capture_output=True, text=True, timeout=120)


def test_episode_writes_a_log_that_analytic_scores_identically(tmp_path):
    out = tmp_path / "ep.mcap"
    simulated = run(
        WORKER, "episode", "--trajectory", "pyramid", "--duration", "3", "--out", str(out), "--json"
    )
    assert simulated.returncode == 0, simulated.stderr
    worker_scores = json.loads(simulated.stdout)
    assert {"f_acc", "f_t", "diverged"} <= worker_scores.keys()
    evaluated = run(ANALYTIC, "evaluate", str(out), "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    assert json.loads(evaluated.stdout) == worker_scores


def test_human_readable_scores(tmp_path):
    out = tmp_path / "ep.mcap"
    result = run(
        WORKER,
        "episode",
        "--trajectory",
        "fourier",
        "--duration",
        "0.5",
        "--out",
        str(out),
        "--model",
        "rigid",
    )
    assert result.returncode == 0, result.stderr
    assert "f_acc" in result.stdout and "mm" in result.stdout


SEVEN = "1,1,1,1,1,1,1"


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--kp", "1,2,3"], "expected 7 numbers"),
        (["--center", "1,2"], "expected 3 numbers"),
        (["--size", "-0.1"], "size"),
        (["--kd", "1,1,1,1,1,1,nan"], "finite and non-negative"),
        (["--kp", "1,1,1,1,1,1,-3"], "finite and non-negative"),
        (["--kp", "one,two"], "comma-separated numbers"),
        (["--trajectory", "circle"], "circle"),
        (["--duration", "0"], "duration"),
        (["--duration", "1e9"], "duration"),
        (["--model", "soft"], "soft"),
        (["--plant", "perfect"], "perfect"),
        (["--trajectory", "pyramid", "--duration", "0.5"], "shortest feasible duration"),
        (["--trajectory", "spiral", "--kp", SEVEN, "--trajectory-seed", "x"], "trajectory-seed"),
    ],
)
def test_bad_input_is_one_clear_line_and_no_file(tmp_path, args, says):
    out = tmp_path / "ep.mcap"
    result = run(WORKER, "episode", "--out", str(out), *args)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("worker: error:")
    assert says in result.stderr
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_unwritable_destination_is_a_clear_error(tmp_path):
    result = run(WORKER, "episode", "--out", str(tmp_path / "missing" / "ep.mcap"))
    assert result.returncode == 2 and "does not exist" in result.stderr


def test_unreachable_path_is_a_clear_error(tmp_path):
    out = tmp_path / "ep.mcap"
    result = run(WORKER, "episode", "--center", "2,0,0.4", "--duration", "0.5", "--out", str(out))
    assert result.returncode == 2, result.stderr
    assert "unreachable" in result.stderr and "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []
