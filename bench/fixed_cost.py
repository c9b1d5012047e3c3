"""What a local run costs beyond its episodes: from `analytic start` to the first job a worker
runs, and from the last episode a worker finishes to the command's exit (the front's logs, the
records, the figures, the report, the farm stopped).

    python bench/fixed_cost.py [--pop 30] [--evaluations 60] [--repeats 3]
                               [--baseline-python PATH] [--baseline-path DIR]

Each repeat runs `python -m gainfarm.analytic start --pop P --evaluations E` (its local farm,
the CLI's default workers, its default held-out check) as a subprocess and takes the times from
the run itself: the worker processes append a mark to a file as each batch of episodes starts
and ends (a `sitecustomize` this script puts first on their PYTHONPATH wraps
`gainfarm.worker.service.execute_batch` as that module loads; nothing else is touched, and the
analytic process loads nothing more). Start: this script's clock as it starts the command;
exit: as the command has exited, its farm stopped.

With --baseline-python (another checkout's interpreter) or --baseline-path (a directory put
first on PYTHONPATH that holds an older `gainfarm` package: its folders laid out as installed),
the same command with that code, alternating with this checkout's, repeat by repeat: the
machine's other load moves every figure, so compare the two columns of one run. Printed: each
figure's median and fastest over the repeats; targets: first job within 2 s, exit within 1 s of
the last episode, both together within 3 s.
"""

import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import click
from common import print_table

FIRST_JOB_TARGET = 2.0  # s from the command's start to a worker's first job
TAIL_TARGET = 1.0  # s from the last episode to the command's exit
FIXED_TARGET = 3.0  # both together

# Put first on the workers' PYTHONPATH: marks every batch's start and end in $FIXED_COST_MARKS.
SITECUSTOMIZE = """
import importlib.abc, importlib.machinery, os, sys, time

TARGET = "gainfarm.worker.service"


def _mark(what):
    with open(os.environ["FIXED_COST_MARKS"], "a") as marks:
        marks.write(f"{what} {time.time():.6f} {os.getpid()}\\n")


class _Wrap(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name != TARGET:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        for finder in sys.meta_path:
            if spec is not None:
                break
            if finder is not self and hasattr(finder, "find_spec"):
                spec = finder.find_spec(name, path, target)
        if spec is None:
            return None
        load = spec.loader.exec_module

        def exec_module(module):
            load(module)
            run = module.execute_batch

            def execute_batch(*args, **kwargs):
                _mark("start")
                try:
                    return run(*args, **kwargs)
                finally:
                    _mark("end")

            module.execute_batch = execute_batch

        spec.loader.exec_module = exec_module
        return spec


if os.environ.get("FIXED_COST_MARKS"):
    sys.meta_path.insert(0, _Wrap())
"""


@dataclass
class Measure:
    first_job_s: float
    tail_s: float
    wall_s: float

    @property
    def fixed_s(self) -> float:
        return self.first_job_s + self.tail_s


def run_once(python: str, path: str | None, pop: int, evaluations: int, scratch: Path) -> Measure:
    """One `analytic start`, its marks read back."""
    hook = scratch / "hook"
    hook.mkdir(exist_ok=True)
    (hook / "sitecustomize.py").write_text(SITECUSTOMIZE)
    marks = scratch / f"marks-{time.monotonic_ns()}.txt"
    out = scratch / f"run-{time.monotonic_ns()}"
    env = dict(os.environ, FIXED_COST_MARKS=str(marks))
    env["PYTHONPATH"] = os.pathsep.join(
        [str(hook), *([path] if path else []), *filter(None, [os.environ.get("PYTHONPATH")])]
    )
    command = [python, "-m", "gainfarm.analytic", "start", "--pop", str(pop)]
    command += ["--evaluations", str(evaluations), "--out", str(out)]
    started = time.time()
    done = subprocess.run(
        command, env=env, cwd=scratch, stdin=subprocess.DEVNULL, capture_output=True, text=True
    )
    ended = time.time()
    if done.returncode != 0:
        raise click.ClickException(f"{' '.join(command)} failed:\n{done.stderr[-2000:]}")
    rows = [line.split() for line in marks.read_text().splitlines()]
    starts = [float(row[1]) for row in rows if row[0] == "start"]
    ends = [float(row[1]) for row in rows if row[0] == "end"]
    return Measure(min(starts) - started, ended - max(ends), ended - started)


@click.command()
@click.option("--pop", default=30, show_default=True)
@click.option("--evaluations", default=60, show_default=True)
@click.option("--repeats", default=3, show_default=True)
@click.option("--baseline-python", help="another checkout's Python, run alternately")
@click.option(
    "--baseline-path",
    type=click.Path(exists=True, file_okay=False),
    help="a directory holding an older gainfarm package, put first on PYTHONPATH",
)
def main(
    pop: int,
    evaluations: int,
    repeats: int,
    baseline_python: str | None,
    baseline_path: str | None,
) -> None:
    cases = {"now": (sys.executable, None)}
    if baseline_python or baseline_path:
        cases["baseline"] = (baseline_python or sys.executable, baseline_path)
    found: dict[str, list[Measure]] = {name: [] for name in cases}
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(repeats):
            for name, (python, path) in cases.items():
                measure = run_once(python, path, pop, evaluations, Path(scratch))
                found[name].append(measure)
                print(
                    f"{name} #{repeat + 1}: first job {measure.first_job_s:.2f} s, last episode "
                    f"to exit {measure.tail_s:.2f} s, wall {measure.wall_s:.2f} s",
                    flush=True,
                )
    rows = []
    for name, measures in found.items():
        for figure, target in (
            ("first_job_s", FIRST_JOB_TARGET),
            ("tail_s", TAIL_TARGET),
            ("fixed_s", FIXED_TARGET),
            ("wall_s", None),
        ):
            values = [getattr(measure, figure) for measure in measures]
            rows.append(
                [
                    name,
                    figure,
                    f"{statistics.median(values):.2f}",
                    f"{min(values):.2f}",
                    "" if target is None else f"<= {target:g}",
                ]
            )
    print_table(["case", "figure", "median s", "fastest s", "target"], "llrrl", rows)


if __name__ == "__main__":
    main()
