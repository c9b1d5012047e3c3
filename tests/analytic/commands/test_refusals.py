"""A refused option is refused before MuJoCo, Zenoh, matplotlib or pymoo load, on each of the three
command lines: each case runs the real command line's group in a fresh interpreter and reads what
it imported (no timing here; bench/cli_startup.py measures the cost)."""

import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("mujoco", "zenoh", "matplotlib", "pymoo")
SCRIPT = f"""
import importlib, sys, click
program = sys.argv[1]
app = importlib.import_module(f"gainfarm.{{program}}.cli").app
try:
    app.main(sys.argv[2:], program, standalone_mode=False)
except click.ClickException as error:
    print("refused:", error.format_message())
else:
    print("ran")
print("heavy:", *sorted({{name.split(".")[0] for name in sys.modules}} & set({HEAVY!r})))
"""
MISSING = "/nonexistent/gainfarm"
CASES = {
    "start --limits": (["analytic", "start", "--limits", MISSING], "--limits: cannot read"),
    "start --center": (["analytic", "start", "--center", "1,2"], "--center: expected 3 numbers"),
    "start --async": (["analytic", "start", "--async", "--algorithm", "nsga3"], "steady state"),
    "start --min-damping": (["analytic", "start", "--min-damping", "3"], "--min-damping"),
    "start --plant FILE": (["analytic", "start", "--plant", __file__], "--plant"),
    "start --connect --local": (
        ["analytic", "start", "--connect", "tcp/a:1", "--local"],
        "exclude",
    ),
    "start --tls": (["analytic", "start", "--tls", MISSING], "--tls needs --connect"),
    "resume --tls": (["analytic", "resume", MISSING, "--tls", MISSING], "--tls needs --connect"),
    "resume RUN": (["analytic", "resume", MISSING], "holds no run"),
    "export RUN": (["analytic", "export", MISSING], "holds no run"),
    "batch --local --connect": (
        ["analytic", "batch", "--local", "--connect", "tcp/a:1"],
        "exclude",
    ),
    "dataset --as": (
        ["analytic", "dataset", MISSING, "--out", MISSING, "--as", "me"],
        "--as needs --tls",
    ),
    "validate --tls": (["analytic", "validate", MISSING, MISSING, "--tls", MISSING], "--tls needs"),
    "dashboard --tls": (["analytic", "dashboard", "--tls", MISSING], "--tls needs --connect"),
    # A gain that is no gain; a count of gains is the robot's to judge, which loads its model.
    "worker episode --kp": (["worker", "episode", "--kp", "1,-2"], "--kp: gains must be finite"),
    "worker episode --center": (["worker", "episode", "--center", "1,2"], "--center"),
    "worker start --tls": (["worker", "start", "--tls", MISSING], "--tls"),
    "worker start --name": (["worker", "start", "--name", "a/b"], "--name"),
    "broker start --tls": (["broker", "start", "--tls", MISSING], "--tls"),
    "broker status --as": (["broker", "status", "--as", "nobody"], "--as"),
    "broker certs --host": (["broker", "certs", MISSING, "--host", "a!b"], "--host"),
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
