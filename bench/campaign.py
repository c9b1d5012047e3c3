"""The paper's whole campaign on one machine: its three experiments, 5 repetitions each,
population 30 (population sizes 10-80 in the population-size experiment), every run to
convergence.

    python bench/campaign.py [--out campaign] [--workers 2] [--reps 5] [--plant realistic|ideal]
    python bench/campaign.py --simulated 2,64 [--job-seconds 0.2] [--reps 1] [--out DIR]
                             [--experiments popsize,generic-vs-specific,speed]

Runs each experiment as its command line (`analytic experiment ...`) in turn, on a local farm,
and prints the wall time of each and of the whole; the reports are in OUT/<experiment>/report.md.

With --simulated N,M,...: the same experiments (the same code, called in this process with each
experiment's runs all at once) on N simulated workers, then on M...: the real broker in its own
process, simulated cobots in load processes (bench/surrogate.py: the real worker code, its batches,
hand-ins and kept logs, around a stand-in for the physics that takes --job-seconds per 5 s episode
and scores with the tuning loop's toy objective). It prints each campaign's wall time and the
strong-scaling efficiency of each against the fewest workers: (T_fewest x N_fewest) / (T x N),
and the share of the workers' time spent in episodes. The surrogate is the same whatever the farm,
so every campaign runs the same evaluations.
"""

import contextlib
import functools
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
from common import SPAWN, broker_process, loopback_endpoint
from surrogate import read_surrogate_log, surrogate

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.experiments.registry import load as load_experiment
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.transport import open_session
from gainfarm.schemas import TrajectorySpec
from gainfarm.schemas.robot import PLANTS
from gainfarm.worker.service import CobotWorker

WORKERS_PER_LOAD = 32  # simulated cobots per load process, each with its own session

EXPERIMENTS = {
    "popsize": ["--sizes", "10,20,30,50,80"],
    "generic-vs-specific": [],
    "speed": ["--durations", "3,4,5,6"],
}


@click.command(help=__doc__.split("\n\n")[0])
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("campaign"),
    show_default=True,
    help="one directory per experiment in it (an existing one is resumed)",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=2,
    show_default=True,
    help="local worker processes",
)
@click.option(
    "--reps",
    type=click.IntRange(min=1),
    default=5,
    show_default=True,
    help="repetitions per experiment",
)
@click.option(
    "--plant",
    type=click.Choice(["realistic", "ideal"]),
    default="realistic",
    show_default=True,
    help="the simulated plant (ideal: the paper's, as the first wave ran it)",
)
@click.option(
    "--experiments",
    "chosen",
    default=",".join(EXPERIMENTS),
    show_default=True,
    callback=lambda _c, _p, text: _experiments(text),
    help="comma-separated: which of the campaign's experiments",
)
@click.option(
    "--simulated",
    callback=lambda _c, _p, text: _counts(text),
    help="comma-separated worker counts: the campaign on each, simulated (see above)",
)
@click.option(
    "--job-seconds",
    type=click.FloatRange(min=0, min_open=True),
    default=0.2,
    show_default=True,
    help="--simulated: the time a simulated 5 s episode takes",
)
def main(
    out: Path,
    workers: int,
    reps: int,
    plant: str,
    simulated: list[int] | None,
    job_seconds: float,
    chosen: list[str],
) -> None:
    if simulated:
        simulated_campaigns(out, simulated, job_seconds, reps, plant, chosen)
        return
    walls: dict[str, float] = {}
    for name in chosen:
        extra = EXPERIMENTS[name]
        started = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-m",
                "gainfarm.analytic",
                "experiment",
                name,
                "--reps",
                str(reps),
                "--workers",
                str(workers),
                "--out",
                str(out / name),
                "--plant",
                plant,
                *extra,
            ],
            check=True,
        )
        walls[name] = time.perf_counter() - started
        print(f"{name}: {walls[name] / 60:.1f} min", flush=True)
    print(f"whole campaign: {sum(walls.values()) / 60:.1f} min on {workers} workers")


def _experiments(text: str) -> list[str]:
    chosen = text.split(",")
    unknown = [name for name in chosen if name not in EXPERIMENTS]
    if unknown or len(set(chosen)) != len(chosen):
        raise click.BadParameter(f"names from {', '.join(EXPERIMENTS)}, each once; got {text!r}")
    return chosen


def _counts(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        counts = [int(part) for part in text.split(",")]
    except ValueError:
        counts = []
    if not counts or min(counts) < 1:
        raise click.BadParameter(f"comma-separated worker counts, got {text!r}")
    return counts


# --- simulated --------------------------------------------------------------------------------


def cobots(
    endpoint: str, names: list[str], job_seconds: float, busy: Any, stop: threading.Event
) -> None:
    """A load process: `names` as simulated cobots until `stop`, their episodes' time in `busy`."""
    run = surrogate(job_seconds, busy)
    farm = [CobotWorker([endpoint], name, simulate=run) for name in names]
    threads = [threading.Thread(target=cobot.serve, args=(stop,)) for cobot in farm]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for cobot in farm:
        cobot.close()


def cpu_seconds(pid: int) -> float:
    """User and system CPU time the process `pid` has used so far (Linux: /proc/PID/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@dataclass
class SimulatedFarm:
    """A simulated farm as the campaign sees it: where its broker is and its processes."""

    endpoint: str
    broker: int  # process ids
    loads: list[int]

    def cpu(self) -> dict[str, float]:
        """CPU seconds so far of the analytic (this process), the broker and the cobots."""
        return {
            "analytic": cpu_seconds(os.getpid()),
            "broker": cpu_seconds(self.broker),
            "cobots": sum(cpu_seconds(pid) for pid in self.loads),
        }


@contextlib.contextmanager
def simulated_farm(workers: int, job_seconds: float, busy: Any):
    """A broker and `workers` simulated cobots, all joined; yields the SimulatedFarm."""
    endpoint = loopback_endpoint()
    stop = SPAWN.Event()
    with broker_process(endpoint, 100_000) as broker:
        names = [f"sim-{index}" for index in range(workers)]
        loads = [
            SPAWN.Process(
                target=cobots,
                args=(endpoint, names[start : start + WORKERS_PER_LOAD], job_seconds, busy, stop),
            )
            for start in range(0, workers, WORKERS_PER_LOAD)
        ]
        for load in loads:
            load.start()
        try:
            session = open_session("client", connect=[endpoint])
            try:
                give_up = time.monotonic() + 30 + workers / 5
                while True:
                    with contextlib.suppress(BrokerUnavailable):
                        if query_status(session, timeout=2.0).worker_count >= workers:
                            break
                    if time.monotonic() > give_up:
                        raise RuntimeError(f"{workers} simulated cobots did not all join")
                    time.sleep(0.2)
            finally:
                session.close()
            yield SimulatedFarm(endpoint, broker.pid, [load.pid for load in loads if load.pid])
        finally:
            stop.set()
            for load in loads:
                load.join(60)
                if load.is_alive():
                    load.kill()


def experiment_runs(
    base: RunConfig, reps: int, chosen: list[str]
) -> dict[str, Callable[[Experiment], None]]:
    """The campaign's `chosen` experiments, as the CLI runs them: each found by its name, with
    its own options at their defaults (the population sizes 10-80, the spirals of 3-6 s)."""
    return {
        name: functools.partial(_run, load_experiment(name).run, base=base, reps=reps)
        for name in chosen
    }


def _run(run: Callable[..., object], experiment: Experiment, base: RunConfig, reps: int) -> None:
    run(experiment, base, reps)


@dataclass
class CampaignFigures:
    """What a simulated campaign measured."""

    wall: float  # s, the experiments one after the other
    utilisation: float  # the workers' time in episodes over workers x wall
    jobs: int  # episodes the broker saw done
    cpu: dict[str, float]  # CPU seconds of the analytic (this process), the broker, the cobots


def simulated_campaign(
    out: Path,
    workers: int,
    job_seconds: float,
    reps: int,
    plant: str,
    chosen: list[str],
    generations: int | None = None,
) -> CampaignFigures:
    """The campaign on `workers` simulated cobots, measured; each run to convergence, or to
    `generations` if given (a smoke run of bench/scale.py)."""
    base = RunConfig(
        pop=30,
        trajectories=(TrajectorySpec(duration=5.0),),
        plant=PLANTS[plant],
        keep="front",
        generations=generations,
    )
    busy = SPAWN.Value("d", 0.0)
    wall = 0.0
    with simulated_farm(workers, job_seconds, busy) as farm:
        endpoint, cpu_before = farm.endpoint, farm.cpu()
        for name, run in experiment_runs(base, reps, chosen).items():

            def client(_name: str, directory: Path) -> FarmClient:
                study = f"sim-{workers}-{directory.parent.name}-{directory.name}"[-64:]
                # Trusted, as a local farm is: these cobots are this script's own, and a referee
                # would run real physics against their surrogate logs.
                return FarmClient(
                    [endpoint],
                    study,
                    directory,
                    keep_logs=False,
                    read_log=read_surrogate_log,
                    trusted=True,
                )

            started = time.perf_counter()
            run(Experiment(out / name, client))
            took = time.perf_counter() - started
            wall += took
            print(f"  {workers} workers, {name}: {took:.1f} s", flush=True)
        time.sleep(0.5)  # the last episodes' time reaches `busy`
        cpu = {part: seconds - cpu_before[part] for part, seconds in farm.cpu().items()}
        jobs = _jobs_done(endpoint)
    per_job = ", ".join(f"{part} {seconds / jobs * 1000:.2f} ms" for part, seconds in cpu.items())
    print(
        f"  {jobs} jobs; CPU per job: {per_job} (of {os.cpu_count()} cores: "
        f"{sum(cpu.values()) / wall / (os.cpu_count() or 1):.0%} of the machine's time)",
        flush=True,
    )
    return CampaignFigures(wall, busy.value / (workers * wall), jobs, cpu)


def _jobs_done(endpoint: str) -> int:
    session = open_session("client", connect=[endpoint])
    try:
        return query_status(session, timeout=5.0).jobs_done
    finally:
        session.close()


def simulated_campaigns(
    out: Path, counts: list[int], job_seconds: float, reps: int, plant: str, chosen: list[str]
) -> None:
    walls = {}
    for workers in counts:
        directory = out / f"simulated-{workers}"
        figures = simulated_campaign(directory, workers, job_seconds, reps, plant, chosen)
        walls[workers] = figures.wall
        print(
            f"campaign on {workers} simulated workers: {figures.wall:.1f} s, the workers in "
            f"episodes {figures.utilisation:.1%} of the time",
            flush=True,
        )
    fewest = min(counts)
    for workers in sorted(set(counts) - {fewest}):
        efficiency = walls[fewest] * fewest / (walls[workers] * workers)
        print(f"strong-scaling efficiency, {workers} against {fewest} workers: {efficiency:.2f}")


if __name__ == "__main__":
    main()
