"""What starting a command line costs, against `python -c "import click"`, in one run of this
script.

    python bench/cli_startup.py [--repetitions 9]

Each command is run as a user runs it (the console scripts next to this Python), round-robin
`--repetitions` times after one unmeasured warm-up, so that a change in the machine's load falls
on every command alike. Printed for each: the median CPU time (user + system of the child,
from getrusage(RUSAGE_CHILDREN)) and the median wall time, each also as a ratio to the anchor's,
and against the targets of issue 27 (a command's help, and a bad option refused, at most 3x the
anchor): PASS or FAIL on the CPU ratio, which the other processes of a shared machine move less
than the wall time. Exit status 1 if a target is missed.
"""

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import click
from common import print_table

BIN = Path(sys.executable).parent
ANCHOR = "python -c 'import click'"
MISSING = "/nonexistent/gainfarm"
BAD_LIMITS = Path(tempfile.gettempdir()) / "gainfarm-cli-startup-limits.json"
# What is run, the exit status it must end with, and its target as a ratio to the anchor.
COMMANDS: dict[str, tuple[list[str], int, float | None]] = {
    ANCHOR: ([sys.executable, "-c", "import click"], 0, None),
    "analytic --help": ([str(BIN / "analytic"), "--help"], 0, 3.0),
    "worker --help": ([str(BIN / "worker"), "--help"], 0, None),
    "broker --help": ([str(BIN / "broker"), "--help"], 0, None),
    "analytic start --pop 0": ([str(BIN / "analytic"), "start", "--pop", "0"], 2, 3.0),
    "analytic start --help": ([str(BIN / "analytic"), "start", "--help"], 0, 3.0),
    # A bad option of each kind a command checks once it runs (a file, a number list, two
    # options that exclude each other), refused before MuJoCo, Zenoh, matplotlib or pymoo load.
    "analytic start --limits BAD": (
        [str(BIN / "analytic"), "start", "--limits", MISSING],
        2,
        3.0,
    ),
    "analytic start --center 1,2": ([str(BIN / "analytic"), "start", "--center", "1,2"], 2, 3.0),
    "analytic resume RUN --tls DIR": (
        [str(BIN / "analytic"), "resume", MISSING, "--tls", MISSING],
        2,
        3.0,
    ),
    "analytic export BAD": ([str(BIN / "analytic"), "export", MISSING], 2, 3.0),
    "analytic batch --local --connect": (
        [str(BIN / "analytic"), "batch", "--local", "--connect", "tcp/127.0.0.1:1"],
        2,
        3.0,
    ),
    "worker episode --kp 1": ([str(BIN / "worker"), "episode", "--kp", "1"], 2, 3.0),
    "broker certs DIR --host BAD": (
        [str(BIN / "broker"), "certs", MISSING, "--host", "a!b"],
        2,
        3.0,
    ),
    # A value only the contract can judge (a limit out of its range): pydantic and NumPy load
    # to refuse it, no target.
    "analytic start --limits (a bad value)": (
        [str(BIN / "analytic"), "start", "--limits", str(BAD_LIMITS)],
        2,
        None,
    ),
}
# The library's face, its target the median wall time in seconds.
IMPORTS: dict[str, tuple[list[str], float]] = {
    "from gainfarm import RunConfig": (
        [sys.executable, "-c", "from gainfarm import RunConfig"],
        0.5,
    ),
    "from gainfarm import tune": ([sys.executable, "-c", "from gainfarm import tune"], 1.5),
}


def measure(command: list[str], status: int) -> tuple[float, float]:
    """One run of `command`: its CPU seconds (user + system) and wall seconds."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    ran = subprocess.run(command, capture_output=True, env={**os.environ, "COLUMNS": "80"})
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if ran.returncode != status:  # not what is meant to be measured (a traceback, say)
        raise SystemExit(
            f"{' '.join(command)}: exit status {ran.returncode}, not {status}\n"
            + ran.stderr.decode(errors="replace")
        )
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall


@click.command()
@click.option("--repetitions", type=click.IntRange(min=1), default=9, show_default=True)
def main(repetitions: int) -> None:
    BAD_LIMITS.write_text('{"torque_step": -1}')
    runs = {name: (command, status) for name, (command, status, _) in COMMANDS.items()}
    runs |= {name: (command, 0) for name, (command, _) in IMPORTS.items()}
    for command, status in runs.values():  # warm-up: files cached, .pyc written
        measure(command, status)
    cpu: dict[str, list[float]] = {name: [] for name in runs}
    wall: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(repetitions):
        for name, (command, status) in runs.items():
            spent, took = measure(command, status)
            cpu[name].append(spent)
            wall[name].append(took)
    anchor_cpu, anchor_wall = statistics.median(cpu[ANCHOR]), statistics.median(wall[ANCHOR])
    rows, missed = [], False
    for name, (_, _, target) in COMMANDS.items():
        cpu_s, wall_s = statistics.median(cpu[name]), statistics.median(wall[name])
        ratio = cpu_s / anchor_cpu
        verdict = ""
        if target is not None:
            verdict = f"{'PASS' if ratio <= target else 'FAIL'} (<= {target:g}x)"
            missed |= ratio > target
        rows.append(
            [
                name,
                f"{cpu_s:.3f}",
                f"{ratio:.2f}x",
                f"{wall_s:.3f}",
                f"{wall_s / anchor_wall:.2f}x",
                verdict,
            ]
        )
    for name, (_, seconds) in IMPORTS.items():
        cpu_s, wall_s = statistics.median(cpu[name]), statistics.median(wall[name])
        missed |= wall_s > seconds
        rows.append(
            [
                name,
                f"{cpu_s:.3f}",
                f"{cpu_s / anchor_cpu:.2f}x",
                f"{wall_s:.3f}",
                f"{wall_s / anchor_wall:.2f}x",
                f"{'PASS' if wall_s <= seconds else 'FAIL'} (wall <= {seconds:g} s)",
            ]
        )
    print(f"median of {repetitions} runs each, round-robin; Python {sys.version.split()[0]}")
    print_table(
        ["command", "CPU s", "CPU vs anchor", "wall s", "wall vs anchor", "target"],
        "lrrrrl",
        rows,
    )
    sys.exit(1 if missed else 0)


if __name__ == "__main__":
    main()
