"""`analytic start --objective NAME`: a run's objectives chosen by name on the command line, a
name this installation lacks refused in one line naming the option, before anything runs."""

import subprocess
import sys
from pathlib import Path

import pytest

ANALYTIC = [sys.executable, "-c", "from gainfarm.analytic.cli import main; main()"]


def start(tmp_path: Path, *arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*ANALYTIC, "start", *arguments, "--out", str(tmp_path / "run"), "--local"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )


@pytest.mark.parametrize(
    ("arguments", "said"),
    [
        (
            ("--objective", "f_acc", "--objective", "jerk"),
            "analytic: error: --objective: gainfarm.objectives: no plug-in named 'jerk' here "
            "(there are f_acc, f_t, f_t_joint",
        ),
        (("--objective", "f_acc"), "analytic: error: --objective: name two objectives"),
        (
            ("--objective", "f_t", "--objective", "f_t"),
            "analytic: error: --objective: 'f_t' twice; name two different ones",
        ),
    ],
)
def test_a_bad_objective_is_one_line_naming_the_option_and_nothing_runs(
    tmp_path: Path, arguments: tuple[str, ...], said: str
) -> None:
    result = start(tmp_path, *arguments)
    assert result.returncode == 2, result.stderr
    assert result.stderr.startswith(said) and result.stderr.count("\n") == 1, result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "run").exists()


def test_the_option_is_listed_with_the_built_ins() -> None:
    shown = subprocess.run(
        [*ANALYTIC, "start", "--help"], capture_output=True, text=True, timeout=60, check=True
    )
    assert "--objective NAME" in shown.stdout and "f_t_joint" in shown.stdout
