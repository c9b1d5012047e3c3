"""A refused option is refused before MuJoCo, Zenoh, matplotlib or pymoo load: each case runs the
real command line's group in a fresh interpreter and reads what it imported (no timing here;
bench/cli_startup.py measures the cost)."""

import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("mujoco", "zenoh", "matplotlib", "pymoo")
SCRIPT = f"""
import sys, click
from gainfarm.analytic.cli import app
try:
    app.main(sys.argv[1:], "analytic", standalone_mode=False)
except click.ClickException as error:
    print("refused:", error.format_message())
else:
    print("ran")
print("heavy:", *sorted({{name.split(".")[0] for name in sys.modules}} & set({HEAVY!r})))
"""
MISSING = "/nonexistent/gainfarm"
CASES = {
    "start --limits": (["start", "--limits", MISSING], "--limits: cannot read"),
    "start --center": (["start", "--center", "1,2"], "--center: expected 3 numbers"),
    "start --async": (["start", "--async", "--algorithm", "nsga3"], "steady state"),
    "start --min-damping": (["start", "--min-damping", "3"], "--min-damping"),
    "start --plant FILE": (["start", "--plant", __file__], "--plant"),
    "start --connect --local": (["start", "--connect", "tcp/a:1", "--local"], "exclude"),
    "start --tls": (["start", "--tls", MISSING], "--tls needs --connect"),
    "resume --tls": (["resume", MISSING, "--tls", MISSING], "--tls needs --connect"),
    "resume RUN": (["resume", MISSING], "holds no run"),
    "export RUN": (["export", MISSING], "holds no run"),
    "batch --local --connect": (["batch", "--local", "--connect", "tcp/a:1"], "exclude"),
    "dataset --as": (["dataset", MISSING, "--out", MISSING, "--as", "me"], "--as needs --tls"),
    "validate --tls": (["validate", MISSING, MISSING, "--tls", MISSING], "--tls needs"),
    "dashboard --tls": (["dashboard", "--tls", MISSING], "--tls needs --connect"),
}


@pytest.mark.parametrize("case", CASES)
def test_a_refused_option_loads_nothing_heavy(case: str, tmp_path: Path) -> None:
    arguments, said = CASES[case]
    ran = subprocess.run(
        [sys.executable, "-c", SCRIPT, *arguments],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert ran.returncode == 0, ran.stderr
    refused, heavy = ran.stdout.splitlines()[-2:]
    assert refused.startswith("refused: ") and said in refused, refused
    assert heavy == "heavy:", f"{case} loaded {heavy.split()[1:]} before refusing"
