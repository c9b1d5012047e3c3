"""The utilisation of many workers on one broker: the share of their time spent on jobs, with
200 simulated workers.

    python bench/utilisation.py [--quick] [--sim-workers 200] [--job-seconds 1] [--window 20]

The broker runs alone in this process. A second process runs the simulated workers (threads over
8 shared sessions, each worker with its own name and liveliness token) that lease a job, sleep for
the job's duration, hand in a no-op Result and, once the broker takes it, put it; the queue is
filled up front, and the submitting client confirms the results it receives with the broker, as
FarmClient does. Utilisation is the time spent sleeping within a window that starts after a
warm-up of two jobs' duration, over the number of workers x the window. The lease latency's 99th
percentile is of the leases asked for within the window; the hand-in latency's is of all.

Everything listens on loopback, on a port the kernel picked as free; nothing touches a farm on 7447.
"""

import math
import threading
import time
from collections import Counter
from dataclasses import dataclass
from multiprocessing.connection import Connection

import click
from common import SPAWN, FakeAnalytic, NoopWorker, loopback_endpoint, percentile_ms

from gainfarm.broker.service import Broker
from gainfarm.edges.transport import open_session

SIM_SESSIONS = 8  # sessions the simulated workers share


def sleepy_load(
    endpoint: str,
    workers: int,
    job_seconds: float,
    warm_up: float,
    window: float,
    parent: Connection,
) -> None:
    """The load: `workers` workers that sleep through each job, and a queue filled beforehand
    with more jobs than they can run in the warm-up and the window."""
    submitter = FakeAnalytic(endpoint, "bench-sleepy")
    jobs = math.ceil(workers * (warm_up + window + 2 * job_seconds + 2) / job_seconds)
    for payload in submitter.submissions(jobs):
        submitter.submit(payload)
    shared = [open_session("client", connect=[endpoint]) for _ in range(SIM_SESSIONS)]
    farm = [
        NoopWorker(shared[i % len(shared)], f"sim-{i}", submitter.study) for i in range(workers)
    ]
    stop = threading.Event()
    threads = [
        threading.Thread(target=worker.serve, args=(stop, lambda: time.sleep(job_seconds)))
        for worker in farm
    ]
    go = time.monotonic()
    for thread in threads:
        thread.start()
    start, end = go + warm_up, go + warm_up + window
    time.sleep(max(end - time.monotonic(), 0.0))
    stop.set()
    for thread in threads:
        thread.join()
    submitter.wait_confirmed(sum(worker.completed for worker in farm))  # the last ones
    runs = [run for worker in farm for run in worker.runs]
    seen = Counter(job_id for job_id, _, _ in runs)
    parent.send(
        {
            "busy": sum(
                max(0.0, min(finish, end) - max(begin, start)) for _, begin, finish in runs
            ),
            "completed": len(runs),
            "repeated": sum(count - 1 for count in seen.values()),
            "submitted": jobs,
            "latencies": [
                latency
                for worker in farm
                for asked, latency in worker.leases
                if start <= asked < end
            ],
            "hand_ins": [latency for worker in farm for latency in worker.hand_ins],
            "refused": sum(worker.refused for worker in farm),
            "confirmed": submitter.confirmed,
            "unconfirmed": submitter.unconfirmed,
        }
    )
    for worker in farm:
        worker.close()
    for session in shared:
        session.close()
    submitter.close()


@dataclass
class Utilisation:
    utilisation: float
    completed: int
    repeated: int  # job runs of a job that had run already (its lease was taken back)
    requeued: int
    p99_ms: float
    hand_in_p99_ms: float
    refused: int  # results the broker did not take
    confirmed: int  # results the submitting client had confirmed


def utilisation(workers: int, job_seconds: float, warm_up: float, window: float) -> Utilisation:
    endpoint = loopback_endpoint()
    with Broker([endpoint]) as broker:
        receiver, sender = SPAWN.Pipe(duplex=False)
        load = SPAWN.Process(
            target=sleepy_load, args=(endpoint, workers, job_seconds, warm_up, window, sender)
        )
        load.start()
        outcome = receiver.recv()
        load.join()
        requeued = broker.queue.requeued
    if outcome["completed"] + workers >= outcome["submitted"]:
        raise RuntimeError("the queue ran dry: the utilisation figure needs more jobs")
    return Utilisation(
        utilisation=outcome["busy"] / (workers * window),
        completed=outcome["completed"],
        repeated=outcome["repeated"],
        requeued=requeued,
        p99_ms=percentile_ms(outcome["latencies"], 99),
        hand_in_p99_ms=percentile_ms(outcome["hand_ins"], 99),
        refused=outcome["refused"],
        confirmed=outcome["confirmed"],
    )


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--quick", is_flag=True, help="a smoke run of under a minute")
@click.option("--sim-workers", type=click.IntRange(min=1), default=200, show_default=True)
@click.option(
    "--job-seconds", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True
)
@click.option(
    "--window",
    type=click.FloatRange(min=0, min_open=True),
    help="s measured  [default: 20; --quick: 4]",
)
def main(quick: bool, sim_workers: int, job_seconds: float, window: float | None) -> None:
    window = window or (4.0 if quick else 20.0)
    warm_up = 2 * job_seconds
    print(
        f"utilisation: {sim_workers} simulated workers, {job_seconds:g} s jobs, "
        f"{window:g} s window after {warm_up:g} s",
        flush=True,
    )
    busy = utilisation(sim_workers, job_seconds, warm_up, window)
    print(
        f"  {busy.completed:,} jobs run, {busy.repeated} of them again after a requeue "
        f"({busy.requeued} requeued); lease latency p99 {busy.p99_ms:.1f} ms in the window; "
        f"hand-in p99 {busy.hand_in_p99_ms:.1f} ms, {busy.refused} refused; "
        f"{busy.confirmed:,} results confirmed"
    )
    print()
    print(
        f"utilisation, {sim_workers} simulated workers sleeping {job_seconds:g} s "
        f"per job: {100 * busy.utilisation:.1f} %"
    )


if __name__ == "__main__":
    main()
