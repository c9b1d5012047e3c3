"""The farm across hosts, for real: every role in its own Linux network namespace, on a LAN.

Each host (the broker, the analytic process, four workers and an operator's console) is a network
namespace with one address on a private /24 and nothing else but `lo`. The LAN is a Linux bridge
in a namespace of its own, the switch, with one veth pair per host: the machine's own network,
routes and firewall (which may well drop bridged traffic) are never touched, and the subnet exists
only inside the namespaces, so it cannot collide with anything. Every process reaches the broker
over real TCP through the bridge, on the explicit endpoint it is given. Needs root and iproute2.
"""

import hashlib
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from gainfarm.analytic.tuning.records import read_history
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import score
from gainfarm.schemas.wire import BrokerStatus, WorkerState
from tests.helpers import wait_for

SUBNET = "10.213.47"
HOSTS = {
    "broker": 2,
    "analytic": 3,
    "worker-1": 4,
    "worker-2": 5,
    "console": 6,
    "worker-3": 7,
    "worker-4": 8,
}
WORKERS = ("worker-1", "worker-2", "worker-3", "worker-4")
BROKER_PORT = 7447
# 10 s spirals: a worker's first one (it computes the trajectory's reference too) takes a few
# hundred ms of wall time, long enough to pull a cable while it runs.
# Without validation by replication: these tests count the run's jobs exactly, and one of them
# takes a worker off the network, which a replica avoiding the other would wait for.
RUN = (
    *("--pop", "4", "--generations", "2", "--duration", "10", "--seed", "0", "--no-replicate"),
    *("--keep", "all"),  # every episode's log, to count them
    *("--check-plants", "0"),  # no held-out check: the jobs are the run's and the baseline's
    *("--plants", "0"),  # one episode a candidate, on the nominal plant: the counts below
    *("--torque-measure", "raw"),  # the paper's f_t: what a log's scores are compared with
)
EVALUATIONS = 8  # pop × generations, one trajectory
JOBS = EVALUATIONS + 1  # and the default gains' episode, once (baseline.json)
LEASE_SECONDS = 2.0
ZENOH_LEASE_SECONDS = 10.0  # Zenoh's default transport lease: a silent link is closed after it
STOP_SECONDS = 15.0  # a worker finishes its episode before leaving on SIGTERM

# An operator's `broker status`, asked every 10 ms and printed as JSON lines: one CLI call per
# look would take a second to start, far too slow to catch a worker in the middle of an episode.
WATCH = """
import sys, time
from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.transport import open_session
while True:
    try:
        session = open_session("client", connect=[sys.argv[1]])
        break
    except ConnectionError:  # the broker is not listening yet
        time.sleep(0.1)
while True:
    try:
        print(query_status(session, timeout=1.0).model_dump_json(), flush=True)
    except BrokerUnavailable:
        pass
    time.sleep(0.01)
"""


def ip(*arguments: str) -> None:
    subprocess.run(["ip", *arguments], check=True, capture_output=True, text=True, timeout=30)


class Lan:
    """Namespaces named after this process (parallel runs do not clash), the processes started
    in them, and their logs."""

    def __init__(self, logs: Path):
        self.prefix = f"gf{os.getpid()}"
        self.switch = f"{self.prefix}-lan"
        self.logs = logs
        self.processes: list[subprocess.Popen] = []

    def namespace(self, host: str) -> str:
        return f"{self.prefix}-{host}"

    def address(self, host: str) -> str:
        return f"{SUBNET}.{HOSTS[host]}"

    @property
    def endpoint(self) -> str:
        return f"tcp/{self.address('broker')}:{BROKER_PORT}"

    def build(self) -> None:
        self.demolish()  # a namespace left by a crashed run that had this pid
        ip("netns", "add", self.switch)
        ip("-n", self.switch, "link", "add", "lan", "type", "bridge")
        ip("-n", self.switch, "link", "set", "lan", "up")
        for host in HOSTS:
            namespace = self.namespace(host)
            ip("netns", "add", namespace)
            ip("-n", namespace, "link", "set", "lo", "up")
            # The switch's port is named after the host; the host sees a plain eth0.
            veth = ("type", "veth", "peer", "eth0", "netns", namespace)
            ip("-n", self.switch, "link", "add", host, *veth)
            ip("-n", self.switch, "link", "set", host, "master", "lan", "up")
            ip("-n", namespace, "addr", "add", f"{self.address(host)}/24", "dev", "eth0")
            ip("-n", namespace, "link", "set", "eth0", "up")

    def demolish(self) -> None:
        for namespace in [self.switch, *map(self.namespace, HOSTS)]:
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True, timeout=30)

    def stop_everything(self) -> None:
        for process in self.processes:
            if process.poll() is None:
                process.terminate()
        for process in self.processes:
            try:
                process.wait(STOP_SECONDS)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()

    def command(self, host: str, *arguments: str) -> list[str]:
        return ["ip", "netns", "exec", self.namespace(host), sys.executable, *arguments]

    def spawn(self, host: str, label: str, *arguments: str) -> subprocess.Popen:
        """Start `python ARGUMENTS` on `host`; its output goes to LABEL.log."""
        with (self.logs / f"{label}.log").open("wb") as log:
            process = subprocess.Popen(
                self.command(host, *arguments),
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                cwd=self.logs,
                env={**os.environ, "COLUMNS": "200"},
            )
        self.processes.append(process)
        return process

    def run(self, host: str, *arguments: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            self.command(host, *arguments),
            capture_output=True,
            text=True,
            timeout=120,
            cwd=self.logs,
            env={**os.environ, "COLUMNS": "200"},
        )

    def start_broker(self, lease_seconds: float) -> subprocess.Popen:
        return self.spawn(
            "broker",
            "broker",
            *("-m", "gainfarm.broker", "start", "--listen", self.endpoint),
            *("--lease-seconds", str(lease_seconds)),
        )

    def start_worker(self, host: str) -> subprocess.Popen:
        return self.spawn(
            host, host, "-m", "gainfarm.worker", "start", "--connect", self.endpoint, "--name", host
        )

    def start_study(self, out: Path) -> subprocess.Popen:
        return self.spawn(
            "analytic",
            "analytic",
            *(
                "-m",
                "gainfarm.analytic",
                "start",
                "--connect",
                self.endpoint,
                *RUN,
                "--out",
                str(out),
            ),
        )

    def watch(self) -> "Watch":
        process = subprocess.Popen(
            self.command("console", "-c", WATCH, self.endpoint),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        self.processes.append(process)
        return Watch(process)

    def unplug(self, host: str) -> None:
        """Pull the host's cable out of the switch: its own eth0 just loses carrier, and no
        process on either side is told anything."""
        ip("-n", self.switch, "link", "set", host, "down")

    def plug(self, host: str) -> None:
        ip("-n", self.switch, "link", "set", host, "up")

    def tail(self, label: str, lines: int = 30) -> str:
        text = (self.logs / f"{label}.log").read_text(errors="replace")
        return f"--- {label}.log ---\n" + "\n".join(text.splitlines()[-lines:])


class Watch:
    """The latest status the console saw, and how many it has seen."""

    def __init__(self, process: subprocess.Popen):
        self.latest: BrokerStatus | None = None
        self.seen = 0
        self._reader = threading.Thread(target=self._read, args=(process,), daemon=True)
        self._reader.start()

    def _read(self, process: subprocess.Popen) -> None:
        for line in process.stdout:
            if line.endswith("\n"):  # the last, when the watch is killed, may be cut short
                self.latest = BrokerStatus.model_validate_json(line)
                self.seen += 1

    def fresh(self) -> BrokerStatus:
        """A status the broker gave after this call: the one being printed now may be older."""
        seen = self.seen
        wait_for(lambda: self.seen >= seen + 2, 10, "a fresh status")
        return self.latest

    def workers(self) -> dict[str, WorkerState]:
        return {worker.name: worker for worker in self.latest.workers} if self.latest else {}

    def busy(self, name: str) -> bool:
        worker = self.workers().get(name)
        return worker is not None and worker.busy


@pytest.fixture
def lan(tmp_path: Path) -> Iterator[Lan]:
    network = Lan(tmp_path)
    try:
        network.build()
        yield network
    finally:
        try:
            network.stop_everything()
        finally:
            network.demolish()


@pytest.fixture(scope="module")
def local_front(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """front.csv of the same run on a farm of one process on this machine, over loopback."""
    out = tmp_path_factory.mktemp("local") / "run"
    command = [
        "-m",
        "gainfarm.analytic",
        "start",
        "--local",
        "--workers",
        "1",
        *RUN,
        "--out",
        str(out),
    ]
    done = subprocess.run(
        [sys.executable, *command],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    return (out / "front.csv").read_bytes()


def check_run(out: Path, local_front: bytes) -> None:
    """The run did every evaluation once and found exactly the local farm's front."""
    history = read_history(out / "history.csv")
    assert [(row.generation, row.evaluations) for row in history] == [(1, 4), (2, EVALUATIONS)]
    assert len(list((out / "episodes").glob("g*.mcap"))) == EVALUATIONS
    assert (out / "episodes" / "baseline-t0.mcap").is_file()  # the default gains, once
    assert (out / "front.csv").read_bytes() == local_front


@pytest.mark.slow
def test_a_study_across_hosts_finds_the_front_a_local_farm_finds(
    lan: Lan, local_front: bytes, tmp_path: Path
) -> None:
    lan.start_broker(lease_seconds=60.0)
    watch = lan.watch()
    for host in WORKERS:
        lan.start_worker(host)
    # All connected and asking for work before the study starts, so that each gets some.
    wait_for(lambda: set(WORKERS) <= set(watch.workers()), 60, "the four workers")
    out = tmp_path / "run"
    study = lan.start_study(out)
    assert study.wait(120) == 0, lan.tail("analytic")
    assert "stopped after 2 generations" in (tmp_path / "analytic.log").read_text()
    check_run(out, local_front)
    # What the broker says, asked by the operator's real command from another host.
    asked = lan.run(
        "console", "-m", "gainfarm.broker", "status", "--connect", lan.endpoint, "--json"
    )
    assert asked.returncode == 0, asked.stderr
    farm = BrokerStatus.model_validate_json(asked.stdout)
    assert farm.jobs_done == JOBS and farm.requeued == 0
    done = {worker.name: worker.jobs_done for worker in farm.workers}
    assert set(done) == set(WORKERS)
    assert all(count >= 1 for count in done.values()), done
    assert sum(done.values()) == JOBS


@pytest.mark.slow
def test_a_worker_cut_off_for_longer_than_its_lease_loses_nothing_and_serves_again(
    lan: Lan, local_front: bytes, tmp_path: Path
) -> None:
    lan.start_broker(lease_seconds=LEASE_SECONDS)
    watch = lan.watch()
    victim = lan.start_worker("worker-1")
    survivor = lan.start_worker("worker-2")
    wait_for(lambda: {"worker-1", "worker-2"} <= set(watch.workers()), 60, "both workers")
    out = tmp_path / "run"
    study = lan.start_study(out)

    # The broker marks a worker busy when it grants the lease, so the cable goes while the
    # victim's episode runs (its first, reference included, takes hundreds of ms).
    wait_for(lambda: watch.busy("worker-1"), 60, "worker-1 to get a job")
    lan.unplug("worker-1")
    cut = time.monotonic()
    held = {worker.name: worker for worker in watch.fresh().workers}["worker-1"]
    assert held.busy, f"worker-1 handed its result in before the cut: {held}"

    # The other worker does its job: a copy, once the job is overdue (three of the study's
    # median turnarounds: broker/queue.py), or the job itself, taken back when the lease runs
    # out, whichever comes first. How many leases were taken back on the way is timing (a 2 s
    # lease on a loaded machine): what holds is that every job was done once, all of the
    # victim's by the other worker.
    assert study.wait(120) == 0, lan.tail("analytic")
    check_run(out, local_front)
    wait_for(lambda: watch.latest.jobs_done == JOBS, 5, "the broker to count the run")
    assert watch.workers()["worker-2"].jobs_done == JOBS - held.jobs_done

    # Out longer than Zenoh's lease too: the broker closes the silent link, and the victim's
    # session its own end (at its lease, or sooner: a put blocked 5 s closes the link).
    wait_for(
        lambda: "worker-1" not in watch.workers(),
        ZENOH_LEASE_SECONDS + 10,
        "the broker to see worker-1 gone",
    )
    time.sleep(max(0.0, cut + ZENOH_LEASE_SECONDS + 2 - time.monotonic()))
    assert victim.poll() is None, lan.tail("worker-1")
    # The victim did finish the episode it held, and could not hand it in before its lease ran
    # out: it never sent the result (and it never counted, checked above).
    assert f"{held.job}: no broker took the result" in (tmp_path / "worker-1.log").read_text()
    lan.plug("worker-1")
    wait_for(lambda: "worker-1" in watch.workers(), 60, "worker-1 to come back")

    # And it serves again: with worker-2 gone, a batch from the analytic host is worker-1's.
    survivor.terminate()
    assert survivor.wait(STOP_SECONDS) == 0
    wait_for(lambda: "worker-2" not in watch.workers(), 10, "worker-2 to leave")
    batch = tmp_path / "batch"
    done = lan.run(
        "analytic",
        *(
            "-m",
            "gainfarm.analytic",
            "batch",
            "--connect",
            lan.endpoint,
            "--trajectory",
            "fourier",
            "--duration",
            "0.5",
        ),
        *("--run-dir", str(batch), "--json"),
    )
    assert done.returncode == 0, done.stderr + lan.tail("worker-1")
    [record] = json.loads((batch / "evaluations.json").read_text())
    assert (record["status"], record["worker"], record["attempts"]) == ("ok", "worker-1", 1)
    wait_for(lambda: watch.workers()["worker-1"].jobs_done == 1, 5, "the broker to count it")


# On the analytic host: four jobs whose logs stay with the workers; prints who ran each, waits for
# a line on stdin, then fetches the four logs from the workers that ran them and prints where
# each came from.
FETCH = """
import json, sys
from pathlib import Path
from gainfarm.analytic.evaluators.evaluator import Wanted
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
endpoint, out = sys.argv[1:3]
specs = {
    f"j{i}": EpisodeSpec(
        gains=DEFAULT_GAINS, trajectory=TrajectorySpec(kind="fourier", duration=1.0 + 0.1 * i)
    )
    for i in range(4)
}
with FarmClient([endpoint], "fetch", Path(out), keep_logs=False) as farm:
    farm.submit(specs)
    done = {e.job_id: e for e in farm.results(120)}
    print(json.dumps({j: [e.worker, e.digest] for j, e in sorted(done.items())}), flush=True)
    sys.stdin.readline()
    wanted = {j: Wanted(e.spec, e.digest, (e.worker,)) for j, e in done.items()}
    got = farm.fetch(wanted)
    print(json.dumps({j: [f.source, f.digest, str(f.log)] for j, f in got.items()}), flush=True)
"""


@pytest.mark.slow
def test_the_fronts_logs_are_fetched_from_the_workers_even_after_the_host_that_made_one_is_gone(
    lan: Lan, local_front: bytes, tmp_path: Path
) -> None:
    lan.start_broker(lease_seconds=60.0)
    watch = lan.watch()
    workers = {host: lan.start_worker(host) for host in WORKERS}
    wait_for(lambda: set(WORKERS) <= set(watch.workers()), 60, "the four workers")

    # A run that keeps its front's logs alone, validated by replication: the workers keep every
    # log, and the front's are fetched from them and scored again here.
    out = tmp_path / "run"
    keep_front = [part for part in RUN if part != "--no-replicate"]
    study = lan.spawn(
        "analytic",
        "analytic",
        *("-m", "gainfarm.analytic", "start", "--connect", lan.endpoint, *keep_front),
        *("--keep", "front", "--out", str(out)),
    )
    assert study.wait(180) == 0, lan.tail("analytic")
    assert (out / "front.csv").read_bytes() == local_front
    for member in json.loads((out / "front.json").read_text())["members"]:
        [log] = member["logs"]
        scores = score(read_episode(out / log))
        assert (scores.f_acc, scores.f_t) == (member["f_acc"], member["f_t"])

    # A log whose worker's host is gone is simulated again elsewhere, to the same bytes.
    fetcher = subprocess.Popen(
        lan.command("analytic", "-c", FETCH, lan.endpoint, str(tmp_path / "fetch")),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=tmp_path,
    )
    lan.processes.append(fetcher)
    ran = json.loads(fetcher.stdout.readline())
    makers = {job: worker for job, (worker, _) in ran.items()}
    gone = makers["j0"]
    lan.unplug(gone)
    workers[gone].kill()
    workers[gone].wait()
    fetcher.stdin.write("go\n")
    fetcher.stdin.flush()
    fetched = json.loads(fetcher.stdout.readline())
    assert fetcher.wait(60) == 0
    for job, (_, digest, path) in fetched.items():
        assert digest == ran[job][1] == hashlib.sha256(Path(path).read_bytes()).hexdigest()
    assert fetched["j0"][0] in set(WORKERS) - {gone}  # run again elsewhere, to the same bytes
    assert {job: fetched[job][0] for job in makers if job != "j0"} == {
        job: worker for job, worker in makers.items() if job != "j0"
    }
