"""What the analytic process costs per evaluation in a real tuning run.

    python bench/analytic_cost.py [--quick] [--pop 30] [--evaluations 600] [--workers 2]
                                  [--seed 0] [--async/--no-async] [--profile]

The default run's configuration (`analytic start`: a 5 s spiral, NSGA-II, keep the front) is
tuned to a fixed budget of evaluations on a local farm (`local_farm`: a broker process and
`--workers` real worker processes running real episodes), through a FarmClient as `analytic
start` makes it (trusted: its own workers). The figure is this process's CPU seconds (every thread
of it: resource.getrusage(RUSAGE_SELF), so a broker that runs in this process, as the local
farm's did before, counts too) over the run, per evaluation, split into the main thread (client,
optimiser, records, checkpoint) and the other threads (Zenoh's, and the client's callbacks on
them). A generation is run first, unmeasured, so the workers
have built the spiral's reference. With --async, a steady-state run is measured too.

With --profile each run is measured again under cProfile, and the main thread's time is split
by what it was doing: the client (FarmClient: submit, results, fetching the front's logs), the
optimiser (ask and tell), the records and the checkpoint, and the rest (the run's own
bookkeeping). cProfile slows Python code, so the split is in shares, not milliseconds.
"""

import cProfile
import pstats
import resource
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import click
from common import print_table

from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import TuningRun

# What the main thread's time is spent on: the functions whose cumulative time counts for each.
PARTS: dict[str, tuple[tuple[str, str], ...]] = {
    "client": (
        ("analytic/evaluators/farm.py", "submit"),
        ("analytic/evaluators/farm.py", "results"),
        ("analytic/evaluators/farm.py", "cancel"),
        ("analytic/evaluators/farm.py", "fetch"),
        ("analytic/evaluators/farm.py", "capacity"),
        ("analytic/evaluators/farm.py", "trusted_capacity"),
    ),
    "optimiser": (
        ("analytic/tuning/evolution.py", "ask"),
        ("analytic/tuning/evolution.py", "tell"),
        ("analytic/tuning/evolution.py", "ask_one"),
        ("analytic/tuning/evolution.py", "tell_one"),
    ),
    "records, checkpoint": (
        ("analytic/tuning/run.py", "write_records"),
        ("analytic/tuning/run.py", "_checkpoint"),
    ),
}


@dataclass(frozen=True)
class Cost:
    evaluations: int
    wall: float  # s
    cpu: float  # s, every thread of this process
    main: float  # s, the main thread alone
    parts: dict[str, float]  # share of the main thread's time (with --profile), by PARTS


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def tune(endpoint: str, config: RunConfig, directory: Path, profile: bool) -> Cost:
    """One run to its budget, as `analytic start` runs it on a local farm, measured."""
    profiler = cProfile.Profile(time.thread_time) if profile else None  # CPU, not waits
    with (
        TuningRun.create(directory, config) as run,
        FarmClient([endpoint], directory.name, directory, keep_logs=False, trusted=True) as farm,
    ):
        wall, cpu, main = time.perf_counter(), cpu_seconds(), time.thread_time()
        if profiler is not None:
            profiler.enable()
        run.run(farm)
        if profiler is not None:
            profiler.disable()
        main = time.thread_time() - main
        cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
    evaluations = run.state.evolution.evaluations
    if evaluations != config.evaluations:
        raise RuntimeError(f"{evaluations} evaluations, not {config.evaluations}")
    failed = sum(ran.digest is None for runs in run.state.provenance.values() for ran in runs)
    if failed:  # an episode that cannot run costs nothing to score: not the run measured
        raise RuntimeError(f"{failed} episodes did not run")
    return Cost(evaluations, wall, cpu, main, _parts(profiler) if profiler else {})


def _parts(profiler: cProfile.Profile) -> dict[str, float]:
    """The main thread's profiled time by PARTS, each a share of the whole."""
    stats = pstats.Stats(profiler)
    total = stats.total_tt  # type: ignore[attr-defined]
    cumulative: dict[tuple[str, str], float] = {}
    for (path, _, name), (_, _, _, cumtime, _) in stats.stats.items():  # type: ignore[attr-defined]
        for part in PARTS.values():
            for suffix, function in part:
                if name == function and path.endswith(suffix):
                    cumulative[(suffix, function)] = cumulative.get((suffix, function), 0) + cumtime
    shares = {
        name: sum(cumulative.get(entry, 0.0) for entry in part) / total
        for name, part in PARTS.items()
    }
    shares["the run's own"] = 1 - sum(shares.values())
    return shares


@click.command()
@click.option("--pop", type=click.IntRange(min=4), default=30, show_default=True)
@click.option("--evaluations", type=click.IntRange(min=1), default=600, show_default=True)
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option(
    "--async/--no-async", "steady", default=True, show_default=True, help="a steady state too"
)
@click.option("--profile", is_flag=True, help="split the main thread's time (cProfile)")
@click.option(
    "--quick", is_flag=True, help="a CI-sized run: 60 evaluations, pop 10, a 0.5 s fourier path"
)
def main(
    pop: int, evaluations: int, workers: int, seed: int, steady: bool, profile: bool, quick: bool
) -> None:
    trajectory = {}
    if quick:
        pop, evaluations = 10, 60
        trajectory = {"trajectories": ({"kind": "fourier", "duration": 0.5},)}
    config = RunConfig.model_validate(
        {"pop": pop, "evaluations": evaluations, "seed": seed, **trajectory}
    )
    kinds = {"generational": config}
    if steady:
        kinds["steady state (--async)"] = config.model_copy(update={"asynchronous": True})
    rows = []
    shares = []
    with tempfile.TemporaryDirectory() as scratch, local_farm(workers) as endpoint:
        warm_up = config.model_copy(update={"evaluations": pop})
        tune(endpoint, warm_up, Path(scratch) / "warm-up", profile=False)
        for index, (kind, chosen) in enumerate(kinds.items()):
            cost = tune(endpoint, chosen, Path(scratch) / f"run-{index}", profile=False)
            per = 1000 / cost.evaluations
            rows.append(
                [
                    kind,
                    str(cost.evaluations),
                    f"{cost.wall:.1f}",
                    f"{cost.evaluations / cost.wall:.1f}",
                    f"{cost.cpu * per:.2f}",
                    f"{cost.main * per:.2f}",
                    f"{(cost.cpu - cost.main) * per:.2f}",
                ]
            )
            if profile:
                profiled = tune(endpoint, chosen, Path(scratch) / f"profiled-{index}", True)
                shares.append([kind, *(f"{share:.0%}" for share in profiled.parts.values())])
    print(
        f"pop {config.pop}, {config.evaluations} evaluations, "
        f"a {config.trajectories[0].duration:g} s {config.trajectories[0].kind}, seed {seed}, "
        f"{workers} worker processes"
    )
    print_table(
        [
            "run",
            "evaluations",
            "wall s",
            "evaluations/s",
            "analytic CPU ms/eval",
            "main thread ms/eval",
            "other threads ms/eval",
        ],
        "lrrrrrr",
        rows,
    )
    if profile:
        print("main thread's profiled time, by what it was doing:")
        print_table(["run", *PARTS, "the run's own"], "l" + "r" * (len(PARTS) + 1), shares)


if __name__ == "__main__":
    main()
