"""The broker's capacity: no-op jobs per second and lease latency, with the rest of the farm in a
second process.

    python bench/broker_capacity.py [--quick] [--jobs 20000] [--runs 3] [--noop-workers 8]
                                    [--batch 1,8]

The broker runs alone in this process. A second process plays the rest of the farm: a client
holding the study's liveliness token that submits, and confirms the results it receives with the
broker in batches as FarmClient does, and K no-op workers, each a thread with its own client
session and liveliness token, that ask for a batch of up to `--batch` leases, at once hand in ok
Results with an empty log with the next request and put those the broker takes. A worker asks for
batches of one when its jobs are long and for bigger ones when they are short (worker/service.py:
about BATCH_SECONDS of work at a time), so the broker answers one query per batch. With 2 cores,
this gives the broker (Zenoh's router, its callbacks, the queue) a core and the load the other,
instead of one GIL for both. Jobs per second is the broker's own count of jobs done (results it
took) over the time from the workers' start to the last completion; lease latency is from a
worker's get to the reply carrying leases, as the worker sees it; hand-in latency from a request
that hands results in to the verdicts. The client's confirmations are counted per round trip
(results asked about at once, and its time), and per result from its arrival to its
confirmation. Two settings, alternating, each run several times
(the figures are those of the run with the median jobs per second):

- "live": the submitter sends Submissions as big as FarmClient's (SUBMIT_CHUNK jobs) while the
  workers run, keeping a few thousand jobs queued: the broker decodes submissions and leases at
  once;
- "pre-filled": every job is queued before the workers start: leasing and results alone.

The CPU time per job of the broker's process (over the same interval) and of the load process is
printed too; the load costs about as much as the broker, so the two cores are near full.

Everything listens on loopback, on a port the kernel picked as free; nothing touches a farm on 7447.
"""

import threading
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection

import click
from common import SPAWN, FakeAnalytic, NoopWorker, loopback_endpoint, percentile_ms

from gainfarm.analytic.evaluators.farm import SUBMIT_CHUNK
from gainfarm.broker.service import Broker
from gainfarm.edges.transport import open_session
from gainfarm.schemas.wire import MAX_BATCH

AHEAD = 2_000  # jobs the live submitter keeps queued beyond those completed


def noop_load(
    endpoint: str, jobs: int, workers: int, prefill: bool, batch: int, parent: Connection
) -> None:
    """The load: a submitter and `workers` no-op workers. Sends the time it starts, works until
    the parent (which sees the broker's count of jobs done) says stop, then sends what it
    measured."""
    submitter = FakeAnalytic(endpoint, "bench-noop")
    payloads = submitter.submissions(jobs)
    if prefill:
        for payload in payloads:
            submitter.submit(payload)
        payloads = []
    sessions = [open_session("client", connect=[endpoint]) for _ in range(workers)]
    farm = [
        NoopWorker(session, f"noop-{i}", submitter.study, batch=batch)
        for i, session in enumerate(sessions)
    ]
    stop = threading.Event()
    threads = [threading.Thread(target=worker.serve, args=(stop,)) for worker in farm]

    def done() -> int:
        return sum(worker.completed for worker in farm)

    parent.send(time.monotonic())
    cpu = time.process_time()
    for thread in threads:
        thread.start()
    for index, payload in enumerate(payloads):
        while index * SUBMIT_CHUNK - done() > AHEAD:
            time.sleep(0.001)
        submitter.submit(payload)
    parent.recv()
    cpu = time.process_time() - cpu
    stop.set()
    for thread in threads:
        thread.join()
    submitter.wait_confirmed(done())  # the last few results are still being confirmed
    parent.send(
        {
            "latencies": [latency for worker in farm for _, latency in worker.leases],
            "hand_ins": [latency for worker in farm for latency in worker.hand_ins],
            "results": done(),
            "refused": sum(worker.refused for worker in farm),
            "confirmed": submitter.confirmed,
            "unconfirmed": submitter.unconfirmed,
            "rounds": submitter.rounds,
            "waits": submitter.waits,
            "cpu": cpu,
        }
    )
    for worker in farm:
        worker.close()
    for session in sessions:
        session.close()
    submitter.close()


@dataclass
class Capacity:
    prefill: bool
    batch: int
    jobs_per_s: float
    p50_ms: float
    p99_ms: float
    broker_us: float  # CPU time of the broker's process per job
    load_us: float  # CPU time of the load process per job
    requeued: int  # leases the broker took back and queued again
    refused: int  # results the broker did not take (a job done already: a duplicate)
    hand_in_p50_ms: float
    hand_in_p99_ms: float
    confirm_rounds: int  # the client's confirmation queries
    confirm_batch: float  # results per confirmation query, on average
    confirm_p50_ms: float  # a confirmation query's round trip
    confirm_p99_ms: float
    wait_p50_ms: float  # a result's arrival at the client to its confirmation
    wait_p99_ms: float


def capacity(jobs: int, workers: int, prefill: bool, batch: int) -> Capacity:
    endpoint = loopback_endpoint()
    with Broker([endpoint]) as broker:
        here, there = SPAWN.Pipe()
        load = SPAWN.Process(
            target=noop_load, args=(endpoint, jobs, workers, prefill, batch, there)
        )
        load.start()
        started: float = here.recv()
        cpu = time.process_time()
        while broker.queue.jobs_done < jobs:  # a poll every 2 ms costs the broker next to nothing
            if not load.is_alive():
                done = broker.queue.jobs_done
                raise RuntimeError(f"the load process ended with {done} of {jobs} jobs done")
            time.sleep(0.002)
        finished, cpu = time.monotonic(), time.process_time() - cpu
        here.send("stop")
        outcome = here.recv()
        load.join()
        requeued = broker.queue.requeued
    if outcome["unconfirmed"] or outcome["confirmed"] != outcome["results"]:
        raise RuntimeError(
            f"{outcome['confirmed']} of {outcome['results']} results confirmed, "
            f"{outcome['unconfirmed']} not"
        )
    rounds = outcome["rounds"]
    return Capacity(
        prefill=prefill,
        batch=batch,
        jobs_per_s=jobs / (finished - started),
        p50_ms=percentile_ms(outcome["latencies"], 50),
        p99_ms=percentile_ms(outcome["latencies"], 99),
        broker_us=cpu / jobs * 1e6,
        load_us=outcome["cpu"] / jobs * 1e6,
        requeued=requeued,
        refused=outcome["refused"],
        hand_in_p50_ms=percentile_ms(outcome["hand_ins"], 50),
        hand_in_p99_ms=percentile_ms(outcome["hand_ins"], 99),
        confirm_rounds=len(rounds),
        confirm_batch=outcome["confirmed"] / len(rounds),
        confirm_p50_ms=percentile_ms((seconds for _, seconds in rounds), 50),
        confirm_p99_ms=percentile_ms((seconds for _, seconds in rounds), 99),
        wait_p50_ms=percentile_ms(outcome["waits"], 50),
        wait_p99_ms=percentile_ms(outcome["waits"], 99),
    )


def capacities(jobs: int, workers: int, runs: int, batch: int) -> tuple[Capacity, Capacity]:
    """The live and the pre-filled setting, alternating; of each, the run with the median
    jobs per second (the upper median for an even number of runs)."""
    found: dict[bool, list[Capacity]] = {False: [], True: []}
    for index in range(runs):
        for prefill in (False, True):
            run = capacity(jobs, workers, prefill, batch)
            found[prefill].append(run)
            print(
                f"  batch {batch}, run {index + 1}/{runs}, "
                f"{'pre-filled' if prefill else 'live'}: "
                f"{run.jobs_per_s:,.0f} jobs/s, lease p50 {run.p50_ms:.1f} ms, "
                f"p99 {run.p99_ms:.1f} ms; CPU per job: broker {run.broker_us:.0f} µs, "
                f"load {run.load_us:.0f} µs; {run.requeued:,} requeued, "
                f"{run.refused:,} results refused",
                flush=True,
            )
            print(
                f"    hand-in p50 {run.hand_in_p50_ms:.1f} ms, p99 {run.hand_in_p99_ms:.1f} ms; "
                f"{run.confirm_rounds:,} confirmations of {run.confirm_batch:.1f} results on "
                f"average, round trip p50 {run.confirm_p50_ms:.1f} ms, p99 "
                f"{run.confirm_p99_ms:.1f} ms; a result confirmed p50 {run.wait_p50_ms:.1f} ms, "
                f"p99 {run.wait_p99_ms:.1f} ms after it arrived",
                flush=True,
            )

    def median(runs: list[Capacity]) -> Capacity:
        return sorted(runs, key=lambda run: run.jobs_per_s)[len(runs) // 2]

    return median(found[False]), median(found[True])


def batch_sizes(_ctx: click.Context, _param: click.Parameter, text: str) -> list[int]:
    try:
        sizes = [int(part) for part in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or any(not 1 <= size <= MAX_BATCH for size in sizes):
        raise click.BadParameter(f"comma-separated sizes from 1 to {MAX_BATCH}, got {text!r}")
    return sizes


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--quick", is_flag=True, help="a smoke run of under a minute")
@click.option(
    "--jobs", type=click.IntRange(min=1), help="per run  [default: 20,000; --quick: 3,000]"
)
@click.option(
    "--runs", type=click.IntRange(min=1), help="runs per setting  [default: 3; --quick: 1]"
)
@click.option("--noop-workers", type=click.IntRange(min=1), default=8, show_default=True)
@click.option(
    "--batch",
    default="1,8",
    show_default=True,
    callback=batch_sizes,
    help="leases a worker asks for at once; each size is measured",
)
def main(
    quick: bool, jobs: int | None, runs: int | None, noop_workers: int, batch: list[int]
) -> None:
    jobs = jobs or (3_000 if quick else 20_000)
    runs = runs or (1 if quick else 3)
    print(f"broker: {jobs:,} no-op jobs per run, {noop_workers} no-op workers", flush=True)
    found = [(size, capacities(jobs, noop_workers, runs, size)) for size in batch]
    print()
    for size, (live, prefilled) in found:
        for run, setting in ((live, "submitting meanwhile"), (prefilled, "queue pre-filled")):
            print(
                f"broker: {run.jobs_per_s:,.0f} no-op jobs/s in batches of {size}, lease latency "
                f"p50 {run.p50_ms:.1f} ms, p99 {run.p99_ms:.1f} ms ({noop_workers} no-op "
                f"workers, {setting}; median of {runs} runs); hand-in p50 "
                f"{run.hand_in_p50_ms:.1f} ms, p99 {run.hand_in_p99_ms:.1f} ms; confirmation "
                f"round trip p50 {run.confirm_p50_ms:.1f} ms, p99 {run.confirm_p99_ms:.1f} ms "
                f"({run.confirm_batch:.1f} results each)"
            )
    if len(found) > 1:
        base = found[0][1][0].jobs_per_s
        for size, (live, _) in found[1:]:
            print(f"batches of {size} against {found[0][0]}, live: {live.jobs_per_s / base:.2f}×")


if __name__ == "__main__":
    main()
