"""What a worker's lies about failures, good candidates' scores and the default gains do to a
run on a farm of two (one rogue, one honest), measured on real processes over Zenoh:

    python bench/rogue_claims.py [--runs 10] [--pop 8] [--generations 6] [--seed 7]
                                 [--good 0.10] [--spot-checks RATE]

A run (its population for its generations, one 0.5 s fourier trajectory on the nominal plant and
2 variants, 3 held-out plants) is first tuned in this process (the calm run: trusted, nothing to
referee), with its baseline, held-out check and report.md. A good candidate's episode is one whose
honest f_acc is within the calm run's best `--good` share. Then, on a farm of a rogue and an honest
worker (tests/analytic/liar.py's):

- `fail`: the rogue says every good candidate's episode failed (once);
- `forge-defaults`: it forges only the default gains' episodes (once);
- `sabotage`: it claims 5 times worse scores for good candidates (`--runs` times, each with a new
  spot key: which episodes are drawn, and which worker runs which, change from run to run).

Printed for each: whether the rogue was named, the evidence, whether the front, baseline.json and
report.md's advice are the calm run's, and the episodes the referee ran again. `--spot-checks`
sets the rate by hand (the default sizes it: analytic.evaluators.replication.sized_rate).
"""

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import click
import numpy as np
from common import print_table

from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import free_port, spawn_worker, stop_workers
from gainfarm.analytic.tuning.check import read_check, run_check
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.plants import HELD_OUT, TUNING, variants
from gainfarm.analytic.tuning.records import read_baseline
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.analytic.view.run_report import write_run_report
from gainfarm.broker.service import Broker
from gainfarm.schemas.robot import REALISTIC_PLANT
from gainfarm.schemas.trajectory import TrajectorySpec

REPO = Path(__file__).resolve().parent.parent


def finish(run: TuningRun, evaluator: Evaluator) -> None:
    """The evolution, then what `analytic start` does after it: baseline, check, report."""
    run.run(evaluator)
    run.baseline(evaluator)
    run_check(run, evaluator)
    write_run_report(run, figures=False)


def advice(run: TuningRun) -> str:
    return (run.directory / "report.md").read_text().splitlines()[2]


def outcome(run: TuningRun, calm: TuningRun) -> dict[str, str]:
    ledger = run.replication
    told, truth = read_baseline(run.directory / "baseline.json"), calm.baseline()
    assert truth is not None
    return {
        "named": ledger.dissenters.get("rogue", "not named"),
        "front": "calm" if run.front() == calm.front() else f"{len(run.front())} rows, steered",
        "baseline": "calm" if told.objectives == truth.objectives else "forged",
        "advice": "calm" if advice(run) == advice(calm) else f"changed: {advice(run)[:60]}",
        "check": "calm"
        if (read_check(run.directory) or {}).get("controllers")
        == (read_check(calm.directory) or {}).get("controllers")
        else "changed",
        "refereed": (
            f"{ledger.refereed} front, {ledger.spot_checked} spot (rate {run.state.spot_rate:.3g}),"
            f" {ledger.failures_checked} failures, {ledger.baseline} baseline, "
            f"{ledger.held_out} check"
        ),
    }


def rogue_run(broker: Broker, config: RunConfig, directory: Path, flags: list[str]) -> TuningRun:
    endpoint = broker.endpoints[0]
    rogue = [sys.executable, "-m", "tests.analytic.liar", endpoint, "rogue", *flags]
    workers = [subprocess.Popen(rogue, cwd=REPO), spawn_worker(endpoint, "h1")]
    try:
        while broker.status().worker_count < 2:
            time.sleep(0.2)
        run = TuningRun.create(directory, config)
        with FarmClient(broker.endpoints, directory.name, directory, keep_logs=False) as farm:
            finish(run, farm)
        return run
    finally:
        stop_workers(workers)


@click.command()
@click.option("--runs", type=click.IntRange(min=1), default=10, show_default=True)
@click.option("--pop", type=click.IntRange(min=4), default=8, show_default=True)
@click.option("--generations", type=click.IntRange(min=1), default=6, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=7, show_default=True)
@click.option("--good", type=click.FloatRange(0, 1), default=0.10, show_default=True)
@click.option("--spot-checks", type=click.FloatRange(0, 1), default=None)
def main(
    runs: int, pop: int, generations: int, seed: int, good: float, spot_checks: float | None
) -> None:
    config = RunConfig(
        pop=pop,
        generations=generations,
        seed=seed,
        trajectories=(TrajectorySpec(kind="fourier", duration=0.5),),
        plants=variants(REALISTIC_PLANT, 2, seed=seed, stream=TUNING),
        check_plants=variants(REALISTIC_PLANT, 3, seed=seed, stream=HELD_OUT),
        spot_checks=spot_checks,
    )
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        calm = TuningRun.create(Path(scratch) / "calm", config)
        finish(calm, InProcessEvaluator(calm.directory))
        f_acc = [
            ran.scores.f_acc
            for episodes in calm.state.provenance.values()
            for ran in episodes
            if ran.scores is not None
        ]
        threshold = repr(float(np.quantile(f_acc, good)))
        print(f"calm: {len(calm.front())} rows; advice: {advice(calm)}")
        plan = [("fail", ["--fail-good", threshold]), ("forge-defaults", ["--forge-defaults"])]
        plan += [("sabotage", ["--sabotage-good", threshold])] * runs
        with Broker([f"tcp/127.0.0.1:{free_port()}"], lease_seconds=30.0) as broker:
            for number, (kind, flags) in enumerate(plan):
                run = rogue_run(broker, config, Path(scratch) / f"r{number}", flags)
                found = outcome(run, calm)
                rows.append([kind, *found.values()])
                print(" | ".join(rows[-1]), flush=True)
    print(f"pop {pop}, {generations} generations, 3 plants, 2 workers, good: best {good:.0%}")
    print_table(
        ["rogue", "named", "front", "baseline", "advice", "check", "refereed"],
        "lllllll",
        rows,
    )
    caught = sum(1 for row in rows if row[0] == "sabotage" and row[1] != "not named")
    print(f"saboteur caught in {caught} of {runs} runs")


if __name__ == "__main__":
    main()
