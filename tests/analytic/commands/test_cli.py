import fcntl
import json
import os
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import threading
import time
from pathlib import Path

import pytest

from gainfarm.analytic.cli import main
from gainfarm.analytic.evaluators.local import free_port, spawn_worker, stop_workers
from gainfarm.analytic.tuning.records import FRONT_FIELDS, read_front_json
from gainfarm.broker.service import Broker
from gainfarm.cli import interrupts
from tests.helpers import analytic, crafted_log, ends_with_closing_lines, write_log

ANALYTIC = [sys.executable, "-c", "from gainfarm.analytic.cli import main; main()"]

CORES = len(os.sched_getaffinity(0))
CORES_WORKERS = f"{CORES} worker{'s' if CORES > 1 else ''}"  # a local farm's, by default


class Refused:
    """What a command line that stops before any farm said: its exit status and stderr."""

    def __init__(self, returncode: int, stderr: str):
        self.returncode, self.stderr = returncode, stderr


@pytest.fixture
def here(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]):
    """`analytic ARGUMENTS` in `cwd`, through the console script's own entry point, in this
    process: for a command refused before any farm, which a process of its own would only
    make slower."""

    def run(*arguments: str, cwd: Path) -> Refused:
        monkeypatch.chdir(cwd)
        monkeypatch.setattr(sys, "argv", ["analytic", *arguments])
        capsys.readouterr()
        try:
            with pytest.raises(SystemExit) as exit:
                main()
        finally:
            interrupts.uninstall()  # the command took Ctrl-C over for its process: give it back
        return Refused(int(exit.value.code or 0), capsys.readouterr().err)

    return run


def test_evaluate_scores_a_crafted_log_from_the_file(tmp_path):
    path = tmp_path / "crafted.mcap"
    write_log(crafted_log(), path)
    result = subprocess.run(
        [*ANALYTIC, "evaluate", str(path), "--json"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    scores = json.loads(result.stdout)
    assert abs(scores["f_acc"] - 0.7 / 3) < 1e-12
    assert abs(scores["f_t"] - 1609.0 / 3) < 1e-9


def test_evaluate_rejects_what_is_not_an_episode_log(tmp_path, here):
    junk = tmp_path / "junk.mcap"
    junk.write_text("not an mcap file")
    for target, says in (
        (junk, "junk.mcap"),
        (tmp_path / "missing.mcap", "no such file"),
        (tmp_path, "is a directory, not an episode log"),
    ):
        result = here("evaluate", str(target), cwd=tmp_path)
        assert result.returncode == 2
        assert result.stderr.startswith("analytic: error:") and result.stderr.count("\n") == 1
        assert says in result.stderr, result.stderr


SEVEN = [1.0] * 7


@pytest.mark.parametrize(
    ("content", "says"),
    [
        ("[]", "the list of candidates is empty"),
        (json.dumps([{"kp": SEVEN, "kd": SEVEN}, {"kp": SEVEN}]), "candidate 2: kd missing"),
        (json.dumps([{"kp": [1, 2], "kd": SEVEN}]), "candidate 1: kp: 2 gains given, 7 needed"),
        (json.dumps({"kp": SEVEN, "kd": [*SEVEN[:6], "x"]}), "kd of A7: 'x' is not a number"),
        ("kp1,kp2\n1,2\n", "'gains': expected columns kp1,kp2,kp3,"),  # not a front.csv
        (",".join(FRONT_FIELDS) + "\n", "is a front.csv with no members"),
        (
            "kp: [1",
            "not JSON or YAML (expected ',' or ']', but got '<stream end>' at line 1 column 7",
        ),
        ("kp: [1]\nkd: [1]", "kp: 1 gains given, 7 needed (A1..A7) (and 1 more problem)"),
        (  # saturates on one encoder count: every tick would, as `worker episode` refuses
            json.dumps({"kp": [1e30, *SEVEN[1:]], "kd": SEVEN}),
            "'gains': kp of A1 is 1e+30, which saturates its motor on one encoder count: every "
            "tick would saturate",
        ),
        (
            "- {kp: [1, 1, 1, 1, 1, 1, 1], kd: [1, 1, 1, 1, 1, 1, 1]}\n"
            "- {kp: [1, 1, 1, 1, 1, 1, 1], kd: [1, 1, 1, 1, 1, 1, 1e+30]}\n",
            "'gains': candidate 2: kd of A7 is 1e+30, which saturates its motor on one encoder "
            "count: every tick would saturate",
        ),
    ],
)
def test_a_bad_gains_file_is_one_line_naming_the_option_before_any_farm(
    tmp_path: Path, content: str, says: str, here
) -> None:
    (tmp_path / "gains").write_text(content)
    ran = here("batch", "--local", "--gains", "gains", "--run-dir", "b", cwd=tmp_path)
    assert ran.returncode == 2, ran.stderr
    assert ran.stderr.startswith("analytic: error: --gains: 'gains'"), ran.stderr
    assert says in ran.stderr and len(ran.stderr.splitlines()) == 1
    assert sorted(path.name for path in tmp_path.iterdir()) == ["gains"]


# --- analytic start: progress on a terminal and off one ---------------------------------------

SHORT_RUN = ["--pop", "4", "--trajectory", "fourier", "--duration", "0.5"]


def on_a_terminal(command: list[str], cwd: Path, columns: int) -> tuple[int, list[str]]:
    """Run `command` with a pseudo-terminal `columns` wide as its stdout and stderr; its exit
    status and every line it drew (each redraw of a live line is one)."""
    leader, follower = os.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))
    environment = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    running = subprocess.Popen(
        command,
        cwd=cwd,
        stdin=follower,
        stdout=follower,
        stderr=follower,
        env={**environment, "TERM": "xterm"},
    )
    os.close(follower)
    drawn = b""
    give_up = time.monotonic() + 300
    while time.monotonic() < give_up:
        ready, _, _ = select.select([leader], [], [], 0.5)
        if ready:
            try:
                chunk = os.read(leader, 65536)
            except OSError:  # the terminal's other side closed: the process is done
                break
            if not chunk:
                break
            drawn += chunk
        elif running.poll() is not None:
            break
    os.close(leader)
    status = running.wait(timeout=60)
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", drawn.decode(errors="replace"))
    return status, [line for line in re.split(r"[\r\n]", text) if line.strip()]


@pytest.mark.slow
def test_start_on_a_terminal_keeps_a_live_line_within_80_columns(tmp_path: Path) -> None:
    status, lines = on_a_terminal(
        [*ANALYTIC, "start", *SHORT_RUN, "--duration", "4", "--generations", "4", "--out", "run"],
        tmp_path,
        80,
    )
    assert status == 0, lines
    assert max(len(line) for line in lines) <= 80, max(lines, key=len)
    live = [line for line in lines if " evals · " in line]
    assert live, lines
    farm = CORES_WORKERS  # a local farm: one worker per core
    assert any(re.search(rf"gen [1-4] · \d+ evals · [\d.]+/s · HV .* · {farm}$", x) for x in live)
    assert not any("nan" in line or "0 workers" in line for line in live), live
    closing = ends_with_closing_lines(lines, tmp_path / "run")
    assert lines[-closing - 2 : -closing] == [
        "stopped after 4 generations",
        "front, history, figures and report in run/",
    ]
    assert not any(line.startswith("generation ") for line in lines)  # plain lines: off one


@pytest.mark.slow
def test_start_off_a_terminal_says_one_line_per_generation_and_keeps_the_front_s_logs(
    tmp_path: Path,
) -> None:
    run = analytic("start", *SHORT_RUN, "--generations", "3", "--out", "run", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    lines = run.stderr.splitlines()
    generations = [line for line in lines if line.startswith("generation ")]
    assert [line.split(":")[0] for line in generations] == [f"generation {n}" for n in (1, 2, 3)]
    for number, line in enumerate(generations, 1):
        # The last says no time left: its budget is spent.
        left = r"; about \d+ (s|min) left of its 12 evaluations at this pace" if number < 3 else ""
        assert re.fullmatch(
            rf"generation {number}: {4 * number} evaluations in [\d.]+ s \([\d.]+/s\), "
            rf"hypervolume 0\.\d{{4}}, best error [\d.]+ mm, {CORES_WORKERS}{left}",
            line,
        ), line
    # The check says itself as it starts: nothing is said for seconds otherwise.
    check = json.loads((tmp_path / "run" / "check.json").read_text())
    assert (
        f"held-out check: {check['cost']['episodes']} episodes on {check['plants']} of the "
        f"{check['asked']} held-out plants asked"
    ) in lines
    closing = ends_with_closing_lines(lines, tmp_path / "run")
    assert lines[-closing - 2 : -closing] == [
        "stopped after 3 generations",
        "front, history, figures and report in run/",
    ]
    # --keep front, the default: the front's logs, and no other.
    assert json.loads((tmp_path / "run" / "config.json").read_text())["keep"] == "front"
    front_logs = {log for m in read_front_json(tmp_path / "run" / "front.json") for log in m.logs}
    assert front_logs
    kept = {f"episodes/{path.name}" for path in (tmp_path / "run" / "episodes").iterdir()}
    assert kept == front_logs


class Lines:
    """A process's stderr, read line by line as it comes, by a thread of its own."""

    def __init__(self, running: subprocess.Popen[str]):
        self.lines: list[str] = []
        self._stream = running.stderr
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self._stream is not None
        for line in self._stream:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, text: str, timeout: float = 120) -> str:
        give_up = time.monotonic() + timeout
        while time.monotonic() < give_up:
            found = [line for line in self.lines if text in line]
            if found:
                return found[0]
            time.sleep(0.05)
        raise AssertionError(f"no line with {text!r} in {timeout} s: {self.lines}")


@pytest.mark.slow
def test_start_says_it_waits_for_workers_while_the_broker_has_none(
    tmp_path: Path, broker: Broker
) -> None:
    endpoint = broker.endpoints[0]
    running = subprocess.Popen(
        [*ANALYTIC, "start", *SHORT_RUN, "--generations", "2", "--connect", endpoint],
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        text=True,
    )
    said = Lines(running)
    worker = None
    try:
        assert said.wait_for("waiting for") == "waiting for workers: the broker has none"
        time.sleep(1.0)  # still waiting, and said once
        assert said.lines == ["waiting for workers: the broker has none"]
        worker = spawn_worker(endpoint, "late")
        assert running.wait(timeout=120) == 0
    finally:
        running.kill()
        if worker is not None:
            stop_workers([worker])
    said._thread.join(timeout=10)
    assert said.lines[:2] == ["waiting for workers: the broker has none", "going on: 1 worker"]
    assert [line.split(":")[0] for line in said.lines[2:4]] == ["generation 1", "generation 2"]


@pytest.mark.slow
def test_start_says_when_it_lost_the_broker_and_waits(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    broker = subprocess.Popen(
        [sys.executable, "-m", "gainfarm.broker", "start", "--listen", endpoint]
    )
    worker = spawn_worker(endpoint, "w")
    command = [*ANALYTIC, "start", *SHORT_RUN, "--generations", "50000", "--connect", endpoint]
    running = subprocess.Popen(
        [*command, "--out", "run"], cwd=tmp_path, stderr=subprocess.PIPE, text=True
    )
    said = Lines(running)
    try:
        said.wait_for("generation 1:")
        broker.kill()
        lost = said.wait_for("broker lost, waiting", timeout=60)
        assert lost.startswith("broker lost, waiting: "), lost
        running.send_signal(signal.SIGINT)
        assert running.wait(timeout=60) == 130
    finally:
        running.kill()
        broker.kill()
        stop_workers([worker])
    said._thread.join(timeout=10)
    assert said.lines[-1].startswith("analytic: stopped after ")
    assert not any("Traceback" in line for line in said.lines)


# --- a start or batch that fails before anything runs leaves nothing ----------------------------


@pytest.mark.parametrize(
    ("endpoint", "says"), [("dead", "cannot open"), ("nonsense", "bad endpoint")]
)
@pytest.mark.parametrize("command", ["start", "batch"])
@pytest.mark.parametrize("there", [False, True])
@pytest.mark.slow
def test_a_farm_that_cannot_be_had_leaves_nothing_behind(
    tmp_path: Path, endpoint: str, says: str, command: str, there: bool
) -> None:
    """No config.json, no episodes/: the same command works once the farm is there."""
    if endpoint == "dead":  # a port nobody listens on, found when the test runs
        endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "runs" / "first"
    if there:
        out.mkdir(parents=True)
    where = ["--out", str(out)] if command == "start" else ["--run-dir", str(out)]
    run = analytic(command, *SHORT_RUN[2:], "--connect", endpoint, *where, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert one_line(run.stderr).startswith(f"analytic: error: --connect: {says}"), run.stderr
    if there:
        assert list(out.iterdir()) == []
    else:
        assert list(tmp_path.iterdir()) == []  # runs/ too: this command made it


@pytest.mark.parametrize(("command", "option"), [("start", "--out"), ("batch", "--run-dir")])
def test_a_directory_that_holds_other_files_is_refused(
    tmp_path: Path, command: str, option: str, here
) -> None:
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    run = here(command, "--local", option, "mine", cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert one_line(run.stderr) == (
        f"analytic: error: {option}: 'mine' is not empty: choose a new or an empty directory"
    )
    assert [path.name for path in mine.iterdir()] == ["notes.txt"]
    run = here(command, "--local", option, "mine/notes.txt", cwd=tmp_path)
    assert one_line(run.stderr).endswith(f"{option}: 'mine/notes.txt' is a file, not a directory")


def one_line(stderr: str) -> str:
    assert stderr.count("\n") == 1 and stderr.endswith("\n"), stderr
    return stderr.rstrip("\n")


@pytest.mark.slow
def test_batch_off_a_terminal_says_its_progress_in_plain_lines(tmp_path: Path) -> None:
    """Every tenth of the jobs (every job, of three), on stderr; none with --json, whose lines
    are the output."""
    candidates = tmp_path / "candidates.json"
    gains = {"kp": [2000, 2000, 1200, 1200, 400, 200, 100], "kd": [60, 60, 40, 40, 10, 5, 2]}
    candidates.write_text(json.dumps([gains] * 3))
    common = ["--local", "--gains", str(candidates), *SHORT_RUN[2:]]
    shown = analytic("batch", *common, "--run-dir", "shown", cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    assert shown.stderr.splitlines() == [f"{n} of 3 evaluated" for n in (1, 2, 3)]
    quiet = analytic("batch", *common, "--run-dir", "quiet", "--json", cwd=tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr
    assert [json.loads(line)["status"] for line in quiet.stdout.splitlines()] == ["ok"] * 3


@pytest.mark.slow
def test_batch_warns_in_one_line_of_a_candidate_far_outside_the_search_space(
    tmp_path: Path,
) -> None:
    """Its episodes still run: the line says which candidate and gain, and why it may be a slip."""
    inside = {"kp": [2000, 2000, 1200, 1200, 400, 200, 100], "kd": [20, 20, 15, 15, 4, 2, 1]}
    far = {**inside, "kd": [20, 20, 1e-6, 15, 4, 2, 1]}
    (tmp_path / "candidates.json").write_text(json.dumps([inside, far]))
    common = ["--local", "--workers", "1", *SHORT_RUN[2:], "--json"]
    ran = analytic("batch", "--gains", "candidates.json", *common, "--run-dir", "b", cwd=tmp_path)
    assert ran.returncode == 0, ran.stderr
    assert ran.stderr == (
        "analytic: warning: --gains 'candidates.json': candidate 2: kd of A3 is 1e-06 N·m·s/rad, "
        "1/1,500,000 of the search space's lowest (1.5 N·m·s/rad: 0.1× the default 15): far "
        "outside what the farm searches (a slip of units or of an exponent?)\n"
    )
    assert [json.loads(line)["status"] for line in ran.stdout.splitlines()] == ["ok"] * 2


def test_a_corrupt_config_is_one_plain_line_on_resume_and_export(tmp_path, here):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text('{"pop": ')
    (run / "front.csv").write_text("")
    for command in ("resume", "export"):
        result = here(command, str(run), cwd=tmp_path)
        assert result.returncode == 2, result.stderr
        assert result.stderr.count("\n") == 1, result.stderr
        assert f"{str(run)!r}: unreadable run (" in result.stderr, result.stderr
        assert "Invalid JSON" in result.stderr and "type=" not in result.stderr, result.stderr
