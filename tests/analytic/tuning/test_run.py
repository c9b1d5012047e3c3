"""Tuning runs end to end on a local farm: the guarantees of `analytic start` and `resume`."""

import itertools
import json
import logging
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import ClassVar

import pytest

from gainfarm.analytic import compose
from gainfarm.analytic.evaluators.farm import FarmClient
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.evaluators.local import (
    LocalFarm,
    free_port,
    local_farm,
    spawn_worker,
    stop_workers,
)
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import read_baseline, read_front, read_history
from gainfarm.analytic.tuning.run import RunProgress, TuningRun
from gainfarm.analytic.view.run_report import write_run_report
from gainfarm.broker.service import Broker
from gainfarm.edges.transport import open_session
from gainfarm.schemas import EpisodeSpec, PDGains, TrajectorySpec, keys
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import balancing_weights, plant_scales, score
from gainfarm.worker.episode import run_episode
from gainfarm.worker.job import execute, simulate
from tests.helpers import analytic, ask_for_work, hand_in, serve_log, wait_for

TINY = RunConfig(
    pop=6,
    seed=7,
    trajectories=(TrajectorySpec(kind="fourier", duration=0.5),),
    generations=3,
    keep="all",  # every episode's log: what the fault tests compare
)


@pytest.fixture(scope="module")
def farm_endpoint() -> Iterator[str]:
    """One local farm (a broker here, 2 worker processes) shared by this module's runs."""
    with local_farm(workers=2) as endpoint:
        yield endpoint


@pytest.fixture(scope="module")
def calm(farm_endpoint: str, tmp_path_factory: pytest.TempPathFactory) -> TuningRun:
    """TINY without faults: what every fault test's run must end with."""
    return tune(tmp_path_factory.mktemp("calm") / "calm", farm_endpoint)


def assert_same_outcome(rough: TuningRun, calm: TuningRun) -> None:
    assert rough.finished and rough.state.stopped == calm.state.stopped
    assert rough.state.evolution.evaluations == calm.state.evolution.evaluations
    front = (rough.directory / "front.csv").read_bytes()
    assert front == (calm.directory / "front.csv").read_bytes()


def tune(directory: Path, endpoint: str, config: RunConfig = TINY, **hooks) -> TuningRun:
    run = TuningRun.create(directory, config)
    with FarmClient([endpoint], f"test-{directory.name}", directory) as farm:
        run.run(farm, **hooks)
        run.baseline(farm)  # as tune() does: the default gains beside the front, and the report
        write_run_report(run)
    return run


@pytest.mark.slow
def test_a_tiny_run_records_everything(tmp_path: Path, farm_endpoint: str) -> None:
    run = tune(tmp_path / "run", farm_endpoint)
    directory = run.directory
    for name in (
        "config.json",
        "checkpoint.pkl",
        "history.csv",
        "front.csv",
        "pareto.png",
        "hypervolume.png",
        "report.md",
        "baseline.json",
    ):
        assert (directory / name).is_file(), name
    assert RunConfig.model_validate_json((directory / "config.json").read_text()) == TINY
    history = read_history(directory / "history.csv")
    assert [row.generation for row in history] == [1, 2, 3]
    assert [row.evaluations for row in history] == [6, 12, 18]
    # The 18 candidates' episodes, and the default gains' one (the run's baseline).
    assert len(list((directory / "episodes").glob("*.mcap"))) == 18 + 1
    baseline = read_baseline(directory / "baseline.json")
    default = score(read_episode(directory / "episodes" / "baseline-t0.mcap"))
    assert baseline.gains == DEFAULT_GAINS and not baseline.diverged
    assert baseline.objectives == (default.f_acc, default.f_t)
    assert run.state.stopped == "3 generations"
    assert "3 generations" in (directory / "report.md").read_text()


def test_the_hypervolume_never_falls_and_the_front_is_non_dominated(
    tmp_path: Path, farm_endpoint: str
) -> None:
    config = TINY.model_copy(update={"generations": 5, "pop": 8})
    run = tune(tmp_path / "run", farm_endpoint, config)
    hypervolumes = [row.hypervolume for row in read_history(run.directory / "history.csv")]
    assert all(later >= earlier for earlier, later in itertools.pairwise(hypervolumes))
    assert hypervolumes[-1] > 0
    front = read_front(run.directory / "front.csv")
    assert len(front) >= 1
    for a, b in itertools.permutations(front, 2):
        dominates = a.f_acc <= b.f_acc and a.f_t <= b.f_t and (a.f_acc, a.f_t) != (b.f_acc, b.f_t)
        assert not dominates
    # And nothing evaluated dominates a front member.
    for f_acc, f_t in run.state.evaluated:
        assert not any(f_acc < m.f_acc and f_t < m.f_t for m in front)


def test_a_front_member_simulated_again_reproduces_its_objectives(
    tmp_path: Path, farm_endpoint: str
) -> None:
    run = tune(tmp_path / "run", farm_endpoint)
    member = read_front(run.directory / "front.csv")[0]
    spec = EpisodeSpec(gains=PDGains(kp=member.kp, kd=member.kd), trajectory=TINY.trajectories[0])
    scores = score(run_episode(spec))
    assert (scores.f_acc, scores.f_t) == (member.f_acc, member.f_t)


@pytest.mark.slow
def test_the_front_is_the_same_in_this_process_as_on_the_farm(
    tmp_path: Path, calm: TuningRun
) -> None:
    run = TuningRun.create(tmp_path / "here", TINY)
    evaluator = InProcessEvaluator(run.directory)
    run.run(evaluator)
    run.baseline(evaluator)  # as the farm's run, so the same episodes are kept
    assert_same_outcome(run, calm)
    assert sorted(p.name for p in (run.directory / "episodes").glob("*.mcap")) == sorted(
        p.name for p in (calm.directory / "episodes").glob("*.mcap")
    )


@pytest.mark.slow
def test_the_front_is_the_same_on_one_worker_as_on_two(tmp_path: Path, farm_endpoint: str) -> None:
    two = tune(tmp_path / "two", farm_endpoint)
    with local_farm(workers=1) as endpoint:
        one = tune(tmp_path / "one", endpoint)
    assert (one.directory / "front.csv").read_bytes() == (two.directory / "front.csv").read_bytes()
    assert [row[:5] for row in _history(one)] == [row[:5] for row in _history(two)]


@pytest.mark.slow
def test_tune_on_a_local_farm_started_early_stops_it_and_finds_the_same_front(
    tmp_path: Path, calm: TuningRun
) -> None:
    # `analytic start` starts its farm before its imports and checks, and hands it to `tune`,
    # which stops it as the report is drawn and waits for it before returning.
    with LocalFarm(workers=2) as farm:
        run = compose.tune(TINY, tmp_path / "run", compose.FarmOptions(local=farm))
        assert all(process.poll() == 0 for process in [farm.broker, *farm.workers])
    assert_same_outcome(run, calm)
    assert (run.directory / "report.md").is_file() and (run.directory / "pareto.png").is_file()


def _history(run: TuningRun) -> list[tuple]:
    return [
        (r.generation, r.evaluations, r.hypervolume, r.best_f_acc, r.best_f_t, r.wall_seconds)
        for r in read_history(run.directory / "history.csv")
    ]


class Interrupt(Exception):
    pass


@pytest.mark.slow
def test_a_stopped_and_resumed_run_ends_where_an_uninterrupted_one_does(
    tmp_path: Path, farm_endpoint: str
) -> None:
    whole = tune(tmp_path / "whole", farm_endpoint)

    def stop_in_generation_two(progress: RunProgress) -> None:
        if progress.generation == 2 and progress.evaluations > 14:
            raise Interrupt  # as Ctrl-C would, halfway through a generation

    stopped = tmp_path / "stopped"
    with pytest.raises(Interrupt):
        tune(stopped, farm_endpoint, on_progress=stop_in_generation_two)
    # The first generation is written; the second too if it ended RECORD_SECONDS after it.
    written = len(read_history(stopped / "history.csv"))
    assert written in (1, 2)
    resumed = TuningRun.open(stopped)
    assert not resumed.finished and len(resumed.state.history) == written
    with FarmClient([farm_endpoint], "test-resumed", stopped) as farm:
        resumed.run(farm, on_progress=lambda _: None)
    assert (stopped / "front.csv").read_bytes() == (whole.directory / "front.csv").read_bytes()


@pytest.mark.slow
def test_start_and_resume_commands(tmp_path: Path) -> None:
    run = analytic(
        "start",
        "--pop",
        "4",
        "--generations",
        "2",
        "--trajectory",
        "fourier",
        "--duration",
        "0.5",
        "--out",
        "run",
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr
    assert "stopped after 2 generations" in run.stderr
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["pop"] == 4 and config["generations"] == 2
    again = analytic("resume", "run", cwd=tmp_path)
    assert again.returncode == 2
    assert again.stderr == "analytic: error: 'run' has finished: 2 generations\n"


@pytest.mark.slow
def test_a_generic_start_is_balanced_by_the_default_gains_unless_told_not_to(
    tmp_path: Path,
) -> None:
    both = ["--trajectory", "fourier", "--trajectory", "spiral", "--duration", "2.6"]
    tiny = ["--pop", "4", "--generations", "1"]
    run = analytic("start", *tiny, *both, "--out", "balanced", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    config = RunConfig.model_validate_json((tmp_path / "balanced" / "config.json").read_text())
    # The default gains' own episodes, simulated here, give the very weights and plant scales
    # the run recorded: its trajectories weighed alike on the nominal plant, its plants scaled
    # alike on each trajectory.
    plants = 1 + len(config.plants)
    assert plants == 3  # robust by default: the nominal plant and two corners
    found = [
        simulate(config.episode_spec(DEFAULT_GAINS, number, plant)).scores.objectives
        for number in range(len(config.trajectories))
        for plant in range(plants)
    ]
    assert config.objective_weights == balancing_weights(found[::plants])
    assert config.plant_scales == plant_scales(found, plants)
    assert "objectives averaged with weights" in (tmp_path / "balanced" / "report.md").read_text()
    plain = analytic("start", *tiny, *both, "--no-balance", "--out", "plain", cwd=tmp_path)
    assert plain.returncode == 0, plain.stderr
    recorded = json.loads((tmp_path / "plain" / "config.json").read_text())
    assert recorded["objective_weights"] is None and "plant_scales" not in recorded


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--pop", "2"], "--pop"),
        (["--generations", "2", "--evaluations", "10"], "--generations and --evaluations exclude"),
        (["--local", "--connect", "tcp/127.0.0.1:7447"], "exclude each other"),
        (["--duration", "500"], "--duration: must be at most 120, got 500"),
        (["--duration", "1"], "--duration: the 1 s spiral is too fast for iiwa14"),
        (["--trajectory", "pyramid", "--duration", "2"], "shortest feasible duration is 2.8 s"),
        (["--center", "2,0,0.4"], "--center/--size: the path is unreachable"),
        (["--trajectory-seed", "-1"], "--trajectory-seed"),
        (["--plant", "perfect"], "--plant"),
        (["--out", "/proc/no/such/dir"], "--out: cannot write"),
        (["--connect", "tcp/127.0.0.1:PORT"], "cannot open a Zenoh client session"),
    ],
)
@pytest.mark.slow
def test_start_refuses_bad_input_in_one_line(
    arguments: list[str], message: str, tmp_path: Path
) -> None:
    arguments = [a.replace("PORT", str(free_port())) for a in arguments]
    run = analytic("start", *arguments, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr.startswith("analytic: error: ") and message in run.stderr
    assert len(run.stderr.splitlines()) == 1


@pytest.mark.slow
def test_resume_of_a_directory_without_a_run_is_one_line(tmp_path: Path) -> None:
    run = analytic("resume", "nothing-here", cwd=tmp_path)
    assert run.returncode == 2
    assert run.stderr == "analytic: error: 'nothing-here' holds no run (no config.json)\n"


def test_a_steady_state_run_records_a_row_every_pop_evaluations(
    tmp_path: Path, farm_endpoint: str
) -> None:
    config = TINY.model_copy(update={"asynchronous": True, "generations": 4})
    run = tune(tmp_path / "run", farm_endpoint, config)
    history = read_history(run.directory / "history.csv")
    assert [row.evaluations for row in history] == [6, 12, 18, 24]
    hypervolumes = [row.hypervolume for row in history]
    assert all(later >= earlier for earlier, later in itertools.pairwise(hypervolumes))
    assert len(run.state.evaluated) >= 24
    assert "steady-state" in (run.directory / "report.md").read_text()


@pytest.mark.slow
def test_the_front_is_the_same_when_a_worker_dies_on_the_way(
    tmp_path: Path, calm: TuningRun
) -> None:
    with Broker([f"tcp/127.0.0.1:{free_port()}"]) as broker:
        endpoint = broker.endpoints[0]
        workers = [spawn_worker(endpoint, "victim"), spawn_worker(endpoint, "survivor")]

        def kill_the_victim(progress: RunProgress) -> None:
            if progress.generation == 1 and workers[0].poll() is None:
                workers[0].kill()

        try:
            rough = tune(tmp_path / "rough", endpoint, on_progress=kill_the_victim)
        finally:
            stop_workers(workers)
        assert workers[0].returncode == -9
    assert_same_outcome(rough, calm)


@pytest.mark.slow
def test_ctrl_c_stops_cleanly_and_resume_goes_on(tmp_path: Path) -> None:
    import signal
    import time

    command = [
        sys.executable,
        "-m",
        "gainfarm.analytic",
        "start",
        "--pop",
        "4",
        "--generations",
        "500",
        "--trajectory",
        "fourier",
        "--duration",
        "0.5",
        "--out",
        "run",
    ]
    running = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    history = tmp_path / "run" / "history.csv"
    give_up = time.monotonic() + 120
    while not (history.exists() and len(read_history(history)) >= 2):
        assert time.monotonic() < give_up and running.poll() is None
        time.sleep(0.1)
    running.send_signal(signal.SIGINT)
    _, err = running.communicate(timeout=60)
    assert running.returncode == 130
    assert "continue with: analytic resume run" in err
    assert "Traceback" not in err
    done = len(read_history(history))
    run = TuningRun.open(tmp_path / "run")
    assert not run.finished and len(run.state.history) == done
    assert run.config.generations == 500


@pytest.mark.slow
def test_the_front_is_the_same_when_the_broker_restarts_mid_run(
    tmp_path: Path, calm: TuningRun
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    brokers = [Broker([endpoint])]
    workers = [spawn_worker(endpoint, f"w{n}") for n in range(2)]

    def restart_the_broker(progress: RunProgress) -> None:
        if progress.generation == 1 and len(brokers) == 1:
            brokers[0].close()  # its queue, leases and study are gone with it
            brokers.append(Broker([endpoint]))

    try:
        rough = tune(tmp_path / "rough", endpoint, on_progress=restart_the_broker)
    finally:
        stop_workers(workers)
        brokers[-1].close()
    assert len(brokers) == 2 and brokers[1].queue.jobs_done > 0
    assert_same_outcome(rough, calm)


@pytest.mark.slow
def test_the_front_is_the_same_when_the_analytic_process_is_killed_and_resumed(
    tmp_path: Path, calm: TuningRun
) -> None:
    with local_farm(workers=2) as endpoint:
        arguments = ["--connect", endpoint]
        config = [
            "--check-plants",  # as `calm`, made without the held-out check
            "0",
            "--pop",
            "6",
            "--seed",
            "7",
            "--trajectory",
            "fourier",
            "--duration",
            "0.5",
            "--generations",
            "3",
            "--keep",  # as `calm` keeps them (RunConfig's default)
            "all",
            *("--plants", "0", "--torque-measure", "raw", "--first-population", "random"),
            *("--aggregate", "cvar"),  # RunConfig's problem, as `calm`'s
        ]
        command = [
            sys.executable,
            "-m",
            "gainfarm.analytic",
            "start",
            *config,
            *arguments,
            "--out",
            "run",
        ]
        running = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.DEVNULL)
        history = tmp_path / "run" / "history.csv"
        # Killed mid-generation two, with its jobs queued and running on the farm.
        wait_for(lambda: history.exists() or running.poll() is not None, 120, "generation one")
        running.kill()
        assert running.wait(10) == -signal.SIGKILL
        assert not TuningRun.open(tmp_path / "run").finished
        resumed = analytic("resume", "run", *arguments, cwd=tmp_path)
        assert resumed.returncode == 0, resumed.stderr
    rough = TuningRun.open(tmp_path / "run")
    assert rough.config == calm.config
    assert_same_outcome(rough, calm)


class Saboteur(threading.Thread):
    """A worker whose logs arrive damaged: it leases jobs and runs them for real, but each log is
    mangled on its way back (truncated, or with bytes flipped in its data): it serves the mangled
    bytes under the log's digest, until it is stopped."""

    DAMAGES: ClassVar[list[Callable[[bytes], bytes]]] = [
        lambda log: log[: len(log) // 2],
        lambda log: log[:4000] + bytes(b ^ 0xFF for b in log[4000:4400]) + log[4400:],
    ]

    def __init__(self, endpoint: str):
        super().__init__(name="saboteur", daemon=True)
        self.endpoint = endpoint
        self.damaged: list[str] = []
        self.stop = threading.Event()

    def run(self) -> None:
        session = open_session("client", connect=[self.endpoint])
        _token = session.liveliness().declare_token(keys.alive_worker("saboteur"))
        served = []
        try:
            for damage in self.DAMAGES:
                lease = None
                while lease is None and not self.stop.is_set():
                    lease = ask_for_work(session, "saboteur")
                if lease is None:
                    return
                result, log = execute(lease, "saboteur")
                # Handed in whole, as a worker does; the damage is in transit.
                assert hand_in(session, result).accepted
                served.append(
                    serve_log(session, lease.study, "saboteur", damage(log), result.digest)
                )
                session.put(
                    keys.result(lease.study, lease.job.job_id), b"", attachment=result.to_bytes()
                )
                self.damaged.append(lease.job.job_id)
            self.stop.wait()  # serving the damaged logs
        finally:
            session.close()


@pytest.mark.slow
def test_the_front_is_the_same_when_a_worker_returns_damaged_logs(
    tmp_path: Path, calm: TuningRun, caplog: pytest.LogCaptureFixture
) -> None:
    with Broker([f"tcp/127.0.0.1:{free_port()}"]) as broker:
        endpoint = broker.endpoints[0]
        saboteur = Saboteur(endpoint)
        saboteur.start()
        # Known to the broker first, the saboteur is sure to take some of the first leases.
        wait_for(
            lambda: "saboteur" in [worker.name for worker in broker.queue.worker_states()],
            what="the saboteur to join",
        )
        worker = spawn_worker(endpoint, "honest")
        try:
            with caplog.at_level(logging.WARNING, logger="gainfarm.analytic"):
                rough = tune(tmp_path / "rough", endpoint)
        finally:
            stop_workers([worker])
            saboteur.stop.set()
            saboteur.join(10)
    assert len(saboteur.damaged) == len(Saboteur.DAMAGES)
    # Each damaged log was refused by its digest as it was fetched.
    refused = [r.getMessage() for r in caplog.records if "are not the ones" in r.getMessage()]
    assert len(refused) == len(Saboteur.DAMAGES)
    assert_same_outcome(rough, calm)
    # Each damaged job was simply run again: every kept log is whole and of its own job.
    for damaged in saboteur.damaged:
        assert read_episode(rough.directory / "episodes" / f"{damaged}.mcap").ticks > 0
