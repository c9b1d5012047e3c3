"""The farm's throughput: its efficiency against a process pool, the broker's capacity, and the
utilisation of many workers.

    python bench/farm_bench.py [--quick] [--only efficiency|broker|utilisation]

1. Farm efficiency. The same N episodes (5 s spirals, gains from 0.8x to 1.2x the defaults, so
   alike but not equal) run through a local farm -- the broker in this process, 2 worker
   processes, a FarmClient that decodes, checks, scores and writes every log into a temporary run
   directory -- and through multiprocessing's Pool(2), whose tasks run the episode and encode its
   log while this process decodes, checks, scores and writes it the same way. The only difference
   is the transport and the broker. Both first run a warm-up batch of 2 episodes per process (the
   first episode in a process compiles the model and computes the reference); then farm and pool
   rounds alternate, and the figure is the median episodes per second of the farm's rounds over
   the median of the pool's.

2. Broker capacity. The broker runs alone in this process. A second process plays the rest of the
   farm: a submitting client holding the study's liveliness token, and K no-op workers, each a
   thread with its own client session and liveliness token, that ask for a lease and at once put
   an ok Result with an empty log. With 2 cores, this gives the broker (Zenoh's router, its
   callbacks, the queue) a core and the load the other, instead of one GIL for both. Jobs per
   second is the broker's own count of jobs done over the time from the workers' start to the
   last completion; lease latency is from a worker's get to the reply carrying a lease, as the
   worker sees it. Two settings, alternating, each run several times (the figures are those of the
   run with the median jobs per second):
   - "live": the submitter sends Submissions as big as FarmClient's (SUBMIT_CHUNK jobs) while the
     workers run, keeping a few thousand jobs queued: the broker decodes submissions and leases
     at once;
   - "pre-filled": every job is queued before the workers start: leasing and results alone.
   The CPU time per job of the broker's process (over the same interval) and of the load process
   is printed too; the load costs about as much as the broker, so the two cores are near full.

3. Utilisation. A second process runs 200 simulated workers (threads over 8 shared sessions, each
   worker with its own name and liveliness token) that lease a job, sleep for the job's duration
   and put a no-op Result; the queue is filled up front. Utilisation is the time spent sleeping
   within a window that starts after a warm-up, over 200 x the window.

Everything listens on loopback, on ports the kernel picked as free; nothing touches a farm on 7447.
"""

import argparse
import json
import math
import multiprocessing
import statistics
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.pool import Pool
from pathlib import Path

import numpy as np
import zenoh

from analytic.farm import SUBMIT_CHUNK, FarmClient
from analytic.local import free_port, local_farm
from broker.service import Broker
from schemas import EpisodeSpec, PDGains, TrajectorySpec, keys
from schemas.files import write_atomically
from schemas.gains import DEFAULT_GAINS
from schemas.mcap_episode import decode_episode, episode_bytes
from schemas.objectives import score
from schemas.transport import open_session
from schemas.wire import (
    LEASE_HOLD_SECONDS,
    BrokerStatus,
    Job,
    JobStatus,
    Result,
    Submission,
    SubmitReply,
    Timings,
    decode,
)
from worker.episode import run_episode

WORKERS = 2  # farm workers and pool processes in the efficiency figure
AHEAD = 2_000  # jobs the live submitter keeps queued beyond those completed
SIM_SESSIONS = 8  # sessions the simulated workers share
ANSWER_SECONDS = 10.0
SPAWN = multiprocessing.get_context("spawn")  # never fork a process that runs Zenoh threads


# --- 1. farm efficiency ------------------------------------------------------------------------


def episode_specs(count: int, duration: float) -> list[EpisodeSpec]:
    """`count` episodes of one spiral, gains from 0.8x to 1.2x the defaults: alike, not equal."""
    kp, kd = DEFAULT_GAINS.kp, DEFAULT_GAINS.kd
    trajectory = TrajectorySpec(duration=duration)
    specs = []
    for index in range(count):
        factor = 0.8 + 0.4 * index / max(count - 1, 1)
        gains = PDGains(kp=tuple(k * factor for k in kp), kd=tuple(k * factor for k in kd))
        specs.append(EpisodeSpec(gains=gains, trajectory=trajectory))
    return specs


def simulate(task: tuple[str, EpisodeSpec]) -> tuple[str, bytes]:
    """A pool task: what a farm worker does with a job, short of putting the result."""
    job_id, spec = task
    return job_id, episode_bytes(run_episode(spec))


def keep(content: bytes, spec: EpisodeSpec, path: Path) -> None:
    """What FarmClient does with a result's log: decode, check, write atomically, score."""
    episode = decode_episode(content, path.name)
    if episode.metadata.spec != spec or episode.metadata.diverged:
        raise RuntimeError(f"{path.name}: not the episode submitted, or diverged")
    write_atomically(path, content)
    score(episode)


def farm_round(farm: FarmClient, specs: list[EpisodeSpec], tag: str) -> float:
    """Episodes per second through the farm, from submission to the last scored result."""
    jobs = {f"{tag}-{index}": spec for index, spec in enumerate(specs)}
    start = time.perf_counter()
    farm.submit(jobs)
    evaluations = list(farm.results(timeout=600))
    elapsed = time.perf_counter() - start
    bad = [e.job_id for e in evaluations if e.status != JobStatus.ok.value]
    if len(evaluations) != len(jobs) or bad:
        raise RuntimeError(f"farm round {tag}: {len(evaluations)} results, not ok: {bad[:5]}")
    return len(specs) / elapsed


def pool_round(pool: Pool, specs: list[EpisodeSpec], episodes: Path, tag: str) -> float:
    """Episodes per second through the pool, this process doing FarmClient's share."""
    by_id = {f"{tag}-{index}": spec for index, spec in enumerate(specs)}
    start = time.perf_counter()
    for job_id, content in pool.imap_unordered(simulate, by_id.items(), chunksize=1):
        keep(content, by_id[job_id], episodes / f"{job_id}.mcap")
    return len(specs) / (time.perf_counter() - start)


@dataclass
class Efficiency:
    farm: list[float]  # episodes/s, one per round
    pool: list[float]
    duplicates: int  # results FarmClient received for jobs it had done already

    @property
    def ratio(self) -> float:
        return statistics.median(self.farm) / statistics.median(self.pool)


def efficiency(count: int, duration: float, rounds: int) -> Efficiency:
    specs = episode_specs(count, duration)
    warm_up = episode_specs(2 * WORKERS, duration)
    outcome = Efficiency([], [], 0)
    with (
        tempfile.TemporaryDirectory() as scratch,
        local_farm(WORKERS) as endpoint,
        FarmClient([endpoint], "bench-efficiency", Path(scratch) / "farm") as farm,
        SPAWN.Pool(WORKERS) as pool,
    ):
        episodes = Path(scratch) / "pool" / "episodes"
        episodes.mkdir(parents=True)
        farm_round(farm, warm_up, "warm")
        pool_round(pool, warm_up, episodes, "warm")
        for index in range(rounds):
            outcome.farm.append(farm_round(farm, specs, f"r{index}"))
            outcome.pool.append(pool_round(pool, specs, episodes, f"r{index}"))
            print(
                f"  round {index + 1}/{rounds}: farm {outcome.farm[-1]:.1f} episodes/s, "
                f"pool {outcome.pool[-1]:.1f} episodes/s",
                flush=True,
            )
        outcome.duplicates = farm.duplicates
    return outcome


# --- the load: the farm around the broker, in a second process ---------------------------------


def query_status(session: zenoh.Session) -> BrokerStatus | None:
    for reply in session.get(keys.STATUS, timeout=1.0):
        if reply.ok is not None:
            return decode(BrokerStatus, reply.ok.payload.to_bytes())
    return None


class Study:
    """A submitting client: the study's liveliness token, and Submissions as prebuilt bytes."""

    def __init__(self, endpoint: str, name: str):
        self.name = name
        self.session = open_session("client", connect=[endpoint])
        self._token = self.session.liveliness().declare_token(keys.alive_study(name))
        give_up = time.monotonic() + ANSWER_SECONDS
        while time.monotonic() < give_up:  # until the broker has seen the token, as FarmClient
            status = query_status(self.session)
            if status is not None and any(study.name == name for study in status.studies):
                return
            time.sleep(0.02)
        raise ConnectionError(f"the broker at {endpoint} never opened study {name}")

    def submissions(self, count: int) -> list[bytes]:
        """`count` jobs of one valid episode spec, in Submissions of SUBMIT_CHUNK jobs."""
        spec = episode_specs(1, 5.0)[0]
        return [
            Submission(
                study=self.name,
                jobs=[
                    Job(job_id=f"j{n}", spec=spec)
                    for n in range(start, min(start + SUBMIT_CHUNK, count))
                ],
            ).to_bytes()
            for start in range(0, count, SUBMIT_CHUNK)
        ]

    def submit(self, payload: bytes) -> None:
        for reply in self.session.get(keys.SUBMIT, payload=payload, timeout=ANSWER_SECONDS):
            if reply.ok is None or decode(SubmitReply, reply.ok.payload.to_bytes()).rejected:
                raise RuntimeError("the broker refused a submission")
            return
        raise RuntimeError("the broker did not answer a submission")

    def close(self) -> None:
        self._token.undeclare()
        self.session.close()


class NoopWorker:
    """Asks for a lease, runs the job (by default: does nothing) and puts an ok Result.

    Replies are read with json, not pydantic: the load should cost as little as it can.
    """

    def __init__(self, session: zenoh.Session, name: str, study: str):
        self.session = session
        self._token = session.liveliness().declare_token(keys.alive_worker(name))
        self._request = json.dumps({"protocol": 1, "worker": name}).encode()
        self._result = Result(
            study=study,
            job_id="x",
            lease_id="x",
            worker=name,
            status=JobStatus.ok,
            episode_bytes=0,
            timings=Timings(simulate_s=0.0, encode_s=0.0),
        ).model_dump(mode="json")
        self.leases: list[tuple[float, float]] = []  # (monotonic time asked, latency s)
        self.runs: list[tuple[str, float, float]] = []  # (job id, start, end) of each job run
        self.empty = 0  # requests answered with "no work"
        self.completed = 0  # results put

    def serve(self, stop: threading.Event, run: Callable[[], None] | None = None) -> None:
        while not stop.is_set():
            asked = time.monotonic()
            lease = None
            for reply in self.session.get(
                keys.LEASE, payload=self._request, timeout=LEASE_HOLD_SECONDS + 5.0
            ):
                if reply.ok is None:
                    raise RuntimeError("the broker refused a lease request")
                lease = json.loads(reply.ok.payload.to_bytes())["lease"]
            if lease is None:
                self.empty += 1
                continue
            self.leases.append((asked, time.monotonic() - asked))
            job_id = lease["job"]["job_id"]
            if run is not None:
                started = time.monotonic()
                run()
                self.runs.append((job_id, started, time.monotonic()))
            result = {**self._result, "job_id": job_id, "lease_id": lease["lease_id"]}
            self.session.put(
                keys.result(lease["study"], job_id),
                b"",
                attachment=json.dumps(result).encode(),
                congestion_control=zenoh.CongestionControl.BLOCK,  # as CobotWorker: no drops
            )
            self.completed += 1

    def close(self) -> None:
        self._token.undeclare()


def noop_load(endpoint: str, jobs: int, workers: int, prefill: bool, parent: Connection) -> None:
    """The load of the broker figure: a submitter and `workers` no-op workers. Sends the time
    it starts, works until the parent (which sees the broker's count of jobs done) says stop,
    then sends what it measured."""
    study = Study(endpoint, "bench-noop")
    payloads = study.submissions(jobs)
    if prefill:
        for payload in payloads:
            study.submit(payload)
        payloads = []
    sessions = [open_session("client", connect=[endpoint]) for _ in range(workers)]
    farm = [NoopWorker(session, f"noop-{i}", study.name) for i, session in enumerate(sessions)]
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
        study.submit(payload)
    parent.recv()
    cpu = time.process_time() - cpu
    stop.set()
    for thread in threads:
        thread.join()
    parent.send(
        {
            "latencies": [latency for worker in farm for _, latency in worker.leases],
            "empty": sum(worker.empty for worker in farm),
            "results": done(),
            "cpu": cpu,
        }
    )
    for worker in farm:
        worker.close()
    for session in sessions:
        session.close()
    study.close()


def sleepy_load(
    endpoint: str,
    workers: int,
    job_seconds: float,
    warm_up: float,
    window: float,
    parent: Connection,
) -> None:
    """The load of the utilisation figure: `workers` workers that sleep through each job."""
    study = Study(endpoint, "bench-sleepy")
    jobs = math.ceil(workers * (warm_up + window + 2 * job_seconds + 2) / job_seconds)
    for payload in study.submissions(jobs):
        study.submit(payload)
    shared = [open_session("client", connect=[endpoint]) for _ in range(SIM_SESSIONS)]
    farm = [NoopWorker(shared[i % len(shared)], f"sim-{i}", study.name) for i in range(workers)]
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
        }
    )
    for worker in farm:
        worker.close()
    for session in shared:
        session.close()
    study.close()


# --- 2. broker capacity ------------------------------------------------------------------------


@dataclass
class Capacity:
    prefill: bool
    jobs_per_s: float
    p50_ms: float
    p99_ms: float
    broker_us: float  # CPU time of the broker's process per job
    load_us: float  # CPU time of the load process per job
    requeued: int  # leases the broker took back and queued again
    duplicates: int  # results for jobs already done
    empty: int  # lease requests answered with "no work"


def capacity(jobs: int, workers: int, prefill: bool) -> Capacity:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Broker([endpoint]) as broker:
        here, there = SPAWN.Pipe()
        load = SPAWN.Process(target=noop_load, args=(endpoint, jobs, workers, prefill, there))
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
    latencies = np.array(outcome["latencies"]) * 1000
    return Capacity(
        prefill=prefill,
        jobs_per_s=jobs / (finished - started),
        p50_ms=float(np.percentile(latencies, 50)),
        p99_ms=float(np.percentile(latencies, 99)),
        broker_us=cpu / jobs * 1e6,
        load_us=outcome["cpu"] / jobs * 1e6,
        requeued=requeued,
        duplicates=outcome["results"] - jobs,
        empty=outcome["empty"],
    )


def capacities(jobs: int, workers: int, runs: int) -> tuple[Capacity, Capacity]:
    """The live and the pre-filled setting, alternating; of each, the run with the median
    jobs per second (the upper median for an even number of runs)."""
    found: dict[bool, list[Capacity]] = {False: [], True: []}
    for index in range(runs):
        for prefill in (False, True):
            run = capacity(jobs, workers, prefill)
            found[prefill].append(run)
            print(
                f"  run {index + 1}/{runs}, {'pre-filled' if prefill else 'live'}: "
                f"{run.jobs_per_s:,.0f} jobs/s, lease p50 {run.p50_ms:.1f} ms, "
                f"p99 {run.p99_ms:.1f} ms; CPU per job: broker {run.broker_us:.0f} µs, "
                f"load {run.load_us:.0f} µs; {run.requeued:,} requeued, "
                f"{run.duplicates:,} duplicate results",
                flush=True,
            )

    def median(runs: list[Capacity]) -> Capacity:
        return sorted(runs, key=lambda run: run.jobs_per_s)[len(runs) // 2]

    return median(found[False]), median(found[True])


# --- 3. utilisation ----------------------------------------------------------------------------


@dataclass
class Utilisation:
    utilisation: float
    completed: int
    repeated: int  # job runs of a job that had run already (its lease was taken back)
    requeued: int
    p99_ms: float


def utilisation(workers: int, job_seconds: float, warm_up: float, window: float) -> Utilisation:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
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
        p99_ms=float(np.percentile(np.array(outcome["latencies"]) * 1000, 99)),
    )


# --- the run -----------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run of under a minute")
    parser.add_argument("--only", choices=["efficiency", "broker", "utilisation"])
    parser.add_argument("--episodes", type=int, help="per round (default 40, quick 10)")
    parser.add_argument("--duration", type=float, default=5.0, help="s per episode")
    parser.add_argument("--rounds", type=int, help="farm and pool rounds (default 5, quick 1)")
    parser.add_argument("--jobs", type=int, help="no-op jobs per run (default 20,000, quick 3,000)")
    parser.add_argument("--runs", type=int, help="broker runs per setting (default 3, quick 1)")
    parser.add_argument("--noop-workers", type=int, default=8)
    parser.add_argument("--sim-workers", type=int, default=200)
    parser.add_argument("--job-seconds", type=float, default=1.0)
    parser.add_argument("--window", type=float, help="s measured (default 20, quick 4)")
    args = parser.parse_args()
    episodes = args.episodes or (10 if args.quick else 40)
    rounds = args.rounds or (1 if args.quick else 5)
    jobs = args.jobs or (3_000 if args.quick else 20_000)
    runs = args.runs or (1 if args.quick else 3)
    window = args.window or (4.0 if args.quick else 20.0)
    warm_up = 2 * args.job_seconds

    summary = []
    if args.only in (None, "efficiency"):
        print(f"farm efficiency: {episodes} x {args.duration:g} s episodes", flush=True)
        farm = efficiency(episodes, args.duration, rounds)
        print(f"  {farm.duplicates} duplicate results")
        summary.append(
            f"farm efficiency ({WORKERS} workers vs Pool({WORKERS}), {episodes} x "
            f"{args.duration:g} s episodes, medians of {rounds} alternating rounds): "
            f"{farm.ratio:.2f}"
        )
    if args.only in (None, "broker"):
        print(f"broker: {jobs:,} no-op jobs per run, {args.noop_workers} no-op workers", flush=True)
        live, prefilled = capacities(jobs, args.noop_workers, runs)
        for run, setting in ((live, "submitting meanwhile"), (prefilled, "queue pre-filled")):
            summary.append(
                f"broker: {run.jobs_per_s:,.0f} no-op jobs/s, lease latency "
                f"p50 {run.p50_ms:.1f} ms, p99 {run.p99_ms:.1f} ms ({args.noop_workers} no-op "
                f"workers, {setting}; median of {runs} runs)"
            )
    if args.only in (None, "utilisation"):
        print(
            f"utilisation: {args.sim_workers} simulated workers, {args.job_seconds:g} s jobs, "
            f"{window:g} s window after {warm_up:g} s",
            flush=True,
        )
        busy = utilisation(args.sim_workers, args.job_seconds, warm_up, window)
        print(
            f"  {busy.completed:,} jobs run, {busy.repeated} of them again after a requeue "
            f"({busy.requeued} requeued); lease latency p99 {busy.p99_ms:.1f} ms in the window"
        )
        summary.append(
            f"utilisation, {args.sim_workers} simulated workers sleeping {args.job_seconds:g} s "
            f"per job: {100 * busy.utilisation:.1f} %"
        )
    print()
    for line in summary:
        print(line)


if __name__ == "__main__":
    main()
