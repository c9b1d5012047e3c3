"""`analytic dashboard`: a real headless Chromium (Debian's, driven by Selenium through Debian's
chromedriver) loads the page while a real run tunes on a real farm (a broker on loopback, a
worker process), and sees the run's front, its hypervolume curve and the farm's line change
without a reload; bad input is one line."""

import base64
import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml
from selenium import webdriver
from selenium.common.exceptions import WebDriverException
from selenium.webdriver.chrome.service import Service

from gainfarm.analytic.evaluators.local import free_port, spawn_worker, stop_workers
from gainfarm.analytic.tuning.records import HISTORY_CSV, read_front, read_history
from gainfarm.analytic.view.dashboard import find_runs, live_first, run_state, run_view
from gainfarm.analytic.view.members import FILE_NAMES
from gainfarm.broker.service import Broker
from gainfarm.models.ur5e import JOINT_NAMES as UR5E_JOINT_NAMES
from tests.helpers import analytic, needs

CHROMIUM, CHROMEDRIVER = shutil.which("chromium"), shutil.which("chromedriver")
NEEDS = "the dashboard's test needs Debian's chromium and chromium-driver (apt-get install them)"


def page_state(browser: webdriver.Chrome, run: str) -> dict:
    """What the page holds now, read from Bokeh's document in the browser."""
    return browser.execute_script(
        """
        const doc = Bokeh.documents[0];
        if (doc === undefined) return null;
        const named = (name) => doc.get_model_by_name(name);
        const run = arguments[0];
        const history = named("history:" + run);
        return {
            farm: named("farm").text,
            farm_points: named("farm-series").data.t.length,
            jobs_per_s: Array.from(named("farm-series").data.jobs_per_s),
            line: history ? named("run:" + run).text : null,
            generations: history ? history.data.evaluations.length : 0,
            front: history ? named("front:" + run).data.f_acc_mm.length : 0,
            evaluated: history ? named("evaluated:" + run).data.f_acc_mm.length : 0,
            baseline: history ? named("baseline:" + run).data.f_acc_mm.length : 0,
            recommended: history ? named("recommended:" + run).data.f_acc_mm.length : 0,
            overlay: Array.from(named("overlay").data.run),
            overlay_points: named("overlay").data.xs.map((xs) => xs.length),
        };
        """,
        run,
    )


@pytest.fixture
def browser() -> Iterator[webdriver.Chrome]:
    needs(bool(CHROMIUM and CHROMEDRIVER), NEEDS)
    chrome = webdriver.ChromeOptions()
    chrome.binary_location = CHROMIUM
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
        chrome.add_argument(argument)
    driver = webdriver.Chrome(options=chrome, service=Service(CHROMEDRIVER))
    try:
        yield driver
    finally:
        driver.quit()


@contextlib.contextmanager
def dashboard(*arguments: str, cwd: Path) -> Iterator[str]:
    """`analytic dashboard ARGUMENTS --port P` in a process of its own; yields the page's
    address once it serves; Ctrl-C ends it (which must then exit 130, having said so)."""
    port = free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "gainfarm.analytic", "dashboard", *arguments, "--port", str(port)],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        first = process.stdout.readline() if process.stdout else ""
        address = f"http://127.0.0.1:{port}/"
        assert first == f"dashboard at {address} (Ctrl-C stops it)\n", process.stderr
        yield address
    finally:
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=30)
    assert process.returncode == 130, stderr
    assert stderr.splitlines()[-1] == "analytic: interrupted", stderr


# A run of some 100 episodes of 3 s: long enough for the page to be seen at several generations.
TUNING = ("--pop", "8", "--generations", "12", "--duration", "3", "--seed", "1", "--no-replicate")


@pytest.mark.slow
def test_the_page_follows_a_run_and_its_farm_live(tmp_path: Path, browser) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    run = runs / "live"
    with Broker([f"tcp/127.0.0.1:{free_port()}"]) as broker:
        endpoint = broker.endpoints[0]
        workers = [spawn_worker(endpoint, "w1")]
        try:
            with dashboard(str(runs), "--connect", endpoint, cwd=tmp_path) as address:
                browser.get(address)
                seen = watch(browser, str(run), lambda state: "1 worker (" in state["farm"])
                assert seen[-1]["line"] is None  # no run yet
                tuning = subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "gainfarm.analytic",
                        "start",
                        "--connect",
                        endpoint,
                        *TUNING,
                        "--out",
                        str(run),
                    ],
                    cwd=tmp_path,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.PIPE,
                    text=True,
                )
                seen += watch(
                    browser,
                    str(run),
                    lambda state: state["generations"] >= 2 or tuning.poll() is not None,
                )
                _, stderr = tuning.communicate(timeout=300)
                assert tuning.returncode == 0, stderr
                history = read_history(run / HISTORY_CSV)
                seen += watch(
                    browser,
                    str(run),
                    lambda s: s["generations"] == len(history) and "report written" in s["line"],
                )
        finally:
            stop_workers(workers)
    # The page changed as the run went, without a reload: the curve grew a point at a time.
    counts = [state["generations"] for state in seen]
    assert counts == sorted(counts) and len({c for c in counts if c > 0}) >= 2, counts
    last = seen[-1]
    assert last["front"] == len(read_front(run / "front.csv"))  # all measured: no divergence
    assert last["evaluated"] == history[-1].evaluations
    assert (
        f"generation {history[-1].generation}, {history[-1].evaluations} evaluations"
        in (last["line"])
    )
    assert "running" in " ".join(state["line"] or "" for state in seen)  # while it ran
    # Every run's curve on the chart that compares them: this one, with all its generations.
    assert last["overlay"] == [str(run)] and last["overlay_points"] == [len(history)], last
    # The default gains on the front's plot, and the recommended member if the run names one.
    advice = (run / "report.md").read_text().splitlines()[2]
    recommends = advice.startswith("**Use front.csv row")
    assert last["baseline"] == 1 and last["recommended"] == int(recommends), last
    assert last["farm_points"] > seen[0]["farm_points"]  # the farm's series grew too
    assert max(max(state["jobs_per_s"], default=0) for state in seen) > 0


def watch(browser: webdriver.Chrome, run: str, until, timeout: float = 240) -> list[dict]:
    """The page's state, looked at every 0.2 s until `until` holds of it: every state seen."""
    seen: list[dict] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with contextlib.suppress(WebDriverException):  # the page's scripts still loading
            state = page_state(browser, run)
            if state is not None:
                if not seen or state != seen[-1]:
                    seen.append(state)
                if until(state):
                    return seen
        time.sleep(0.2)
    raise AssertionError(f"the page never got there: {json.dumps(seen[-3:])}")


def test_a_run_reads_as_its_files_say(tmp_path: Path) -> None:
    """The page's view of a run is its records': a run found under a directory of runs, a run
    that has not written its config yet said to be starting, a broken file said in its line."""
    (tmp_path / "a" / "episodes" / "deep").mkdir(parents=True)
    (tmp_path / "a" / "config.json").write_text("{")
    (tmp_path / "b").mkdir()
    assert find_runs([tmp_path]) == [tmp_path / "a"]
    assert run_view(tmp_path / "b").line == "starting: no config.json yet"
    broken = run_view(tmp_path / "a")
    assert broken.line.startswith("cannot read: ") and broken.history["evaluations"] == []


def test_a_run_is_running_while_its_process_holds_it_and_the_live_and_newest_come_first(
    tmp_path: Path,
) -> None:
    import os

    from gainfarm.edges.files import Lock, lock_held

    older, newer = tmp_path / "older", tmp_path / "newer"
    for age, directory in enumerate((newer, older)):
        directory.mkdir()
        (directory / "config.json").write_text("{}")
        os.utime(directory / "config.json", ns=(10**18 - age * 10**12,) * 2)
    assert run_state(older) == "stopped: `analytic resume` continues it"
    assert live_first([older, newer]) == [newer, older]  # the newest first
    lock = Lock(older / "run.lock")  # a process writing it: this one
    assert lock_held(older / "run.lock") is True and lock_held(newer / "run.lock") is False
    assert run_state(older) == "running"
    assert live_first([newer, older]) == [older, newer]  # the running one first
    lock.release()
    assert lock_held(older / "run.lock") is False and run_state(older).startswith("stopped")
    (older / "report.md").write_text("done")
    assert run_state(older) == "report written"


@pytest.mark.slow
def test_bad_options_are_one_line(tmp_path: Path) -> None:
    for arguments, expected in (
        (("nowhere",), "analytic: error: RUNS: 'nowhere': no such directory"),
        (("--tls", "x"), "analytic: error: --tls needs --connect: the farm to watch"),
        (("--port", "0"), "analytic: error: Invalid value for '--port'"),
    ):
        run = analytic("dashboard", *arguments, cwd=tmp_path)
        assert run.returncode == 2, run.stderr
        assert run.stderr.startswith(expected) and run.stderr.count("\n") == 1, run.stderr


def test_without_bokeh_the_command_says_which_extra(tmp_path: Path) -> None:
    without = (
        "import sys; sys.modules['bokeh'] = None; sys.argv = ['analytic', 'dashboard', "
        f"'--port', '{free_port()}']; from gainfarm.analytic.cli import main; main()"
    )
    run = subprocess.run(
        [sys.executable, "-c", without], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 2
    assert run.stderr == (
        "analytic: error: the dashboard needs Bokeh: pip install 'gainfarm[dashboard]'\n"
    )


@pytest.mark.slow
def test_a_port_in_use_is_one_line(tmp_path: Path) -> None:
    with Broker([f"tcp/127.0.0.1:{free_port()}"]) as broker:
        taken = int(broker.endpoints[0].rsplit(":", 1)[1])
        run = analytic("dashboard", "--port", str(taken), cwd=tmp_path)
    assert run.returncode == 2
    assert run.stderr.startswith(f"analytic: error: --port: cannot serve on {taken}: ")
    assert run.stderr.count("\n") == 1, run.stderr
    assert os.listdir(tmp_path) == []


# A finished run in seconds: two trajectories' worth of episodes is not needed, one is.
QUICK = (
    "--trajectory", "fourier", "--duration", "0.5", "--pop", "4", "--generations", "2",
    "--seed", "3", "--local",
)  # fmt: skip

# The page's DOM is in Bokeh's shadow roots: a selector is looked for through them.
FIND = """
const find = (root, selector) => {
    const hit = root.querySelector(selector);
    if (hit) return hit;
    for (const element of root.querySelectorAll("*")) {
        const found = element.shadowRoot && find(element.shadowRoot, selector);
        if (found) return found;
    }
    return null;
};
const findAll = (root, selector) => [
    ...root.querySelectorAll(selector),
    ...[...root.querySelectorAll("*")].flatMap(
        (element) => (element.shadowRoot ? findAll(element.shadowRoot, selector) : [])
    ),
];
"""


def inspector_state(browser: webdriver.Chrome) -> dict:
    return browser.execute_script(
        FIND
        + """
        const doc = Bokeh.documents[0];
        if (doc === undefined) return null;
        const named = (name) => doc.get_model_by_name(name);
        const figures = [...doc.all_models].filter((m) => m.outer_width !== undefined);
        return {
            inspect: named("inspect").value,
            runs: Array.from(named("inspect").options),
            chosen: Array.from(named("chosen-runs").value),
            overlay: Array.from(named("overlay").data.run),
            fronts: Array.from(named("fronts").data.run),
            front_xs: named("fronts").data.xs.map((xs) => Array.from(xs)),
            front_ys: named("fronts").data.ys.map((ys) => Array.from(ys)),
            rows: Array.from(named("members").data.row),
            selected: Array.from(named("members").selected.indices),
            recommendation: named("recommendation").text,
            export: named("export").text,
            episode: named("episode").text,
            ticks: named("episode-joints").data.t.length,
            error_mm: Array.from(named("episode-error").data.error_mm),
            first_row: (findAll(document, ".slick-row")
                .map((row) => [row.getBoundingClientRect().top, row])
                .filter(([top]) => top > 0)
                .sort((a, b) => a[0] - b[0])
                .map(([, row]) => row.querySelector(".slick-cell"))
                .find((cell) => cell) || {}).textContent,
            window: window.innerWidth,
            widths: figures.map((figure) => figure.outer_width),
        };
        """
    )


def until(browser: webdriver.Chrome, holds, timeout: float = 60) -> dict:
    """The inspector's state once `holds` of it."""
    state = None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with contextlib.suppress(WebDriverException):
            state = inspector_state(browser)
            if state is not None and holds(state):
                return state
        time.sleep(0.2)
    raise AssertionError(f"the page never got there: {json.dumps(state)[:3000]}")


def js(browser: webdriver.Chrome, statement: str, *arguments: object) -> object:
    return browser.execute_script(
        FIND
        + "const doc = Bokeh.documents[0]; const named = (n) => doc.get_model_by_name(n);"
        + statement,
        *arguments,
    )


@pytest.mark.slow
def test_runs_compare_and_a_member_is_inspected_exported_and_its_episode_plotted(
    tmp_path: Path, browser
) -> None:
    from gainfarm.analytic.tuning.evolution import normalise
    from gainfarm.schemas.mcap_episode import read_episode

    runs = tmp_path / "runs"
    made = analytic("start", *QUICK, "--out", str(runs / "a"), cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    shutil.copytree(runs / "a", runs / "b")  # a second run to compare, newer
    (runs / "b" / "config.json").touch()
    a, b = str(runs / "a"), str(runs / "b")
    front = read_front(runs / "a" / "front.csv")
    downloads = tmp_path / "downloads"
    downloads.mkdir()
    browser.execute_cdp_cmd(
        "Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)}
    )
    browser.set_window_size(1400, 1000)
    with dashboard(str(runs), cwd=tmp_path) as address:
        browser.get(address)
        # Both runs compared, each front in the hypervolume's space; the newest inspected.
        state = until(browser, lambda s: sorted(s["fronts"]) == [a, b] and s["rows"])
        assert state["inspect"] == b and state["runs"] == [b, a] and state["chosen"] == [b, a]
        expected = normalise(sorted(member.objectives for member in front))
        for xs, ys in zip(state["front_xs"], state["front_ys"], strict=True):
            assert np.allclose(xs, expected[:, 0]) and np.allclose(ys, expected[:, 1])
        # The plots share the window's width, two to a row: not a fixed 480 px.
        assert max(state["widths"]) > 0.45 * state["window"], state["widths"]
        # One run taken out of the comparison: both charts drop it.
        js(browser, "named('chosen-runs').value = arguments[0];", [a])
        until(browser, lambda s: s["fronts"] == [a] and s["overlay"] == [a])
        # The other run inspected: its table, sortable; a member chosen in it.
        js(browser, "named('inspect').value = arguments[0];", a)
        state = until(browser, lambda s: s["inspect"] == a and s["rows"])
        assert state["rows"] == list(range(1, len(front) + 1))
        # The default 64 held-out plants asked, fewer run: a short run's check is cut to size.
        assert re.search(HELD_OUT_SAID, state["recommendation"]), state["recommendation"]
        assert "of the 64 asked: the check&#x27;s budget" in state["recommendation"]
        assert state["first_row"] == "1"  # by row: the most accurate first
        header = f"{front[0].names[1]} ((N·m)²)"  # the run's second objective, by name
        js(browser, "findAll(document, '.slick-header-column').find("
           "(c) => c.textContent.trim() === arguments[0]).click();", header)  # fmt: skip
        smoothest = min(range(len(front)), key=lambda k: (front[k].objectives[1], k)) + 1
        until(browser, lambda s: s["first_row"] == str(smoothest))
        row = len(front)  # the least accurate: not one of the picks necessarily
        js(browser, "named('members').selected.indices = [arguments[0]];", row - 1)
        state = until(browser, lambda s: s["ticks"] > 0 and f"row {row} as" in s["export"])
        log = front[row - 1].logs if front[row - 1].logs else None
        assert log is None  # front.csv holds no logs: front.json does
        members = read_front_json_sorted(runs / "a")
        kept = read_episode(runs / "a" / members[row - 1].logs[0])
        assert state["episode"] == (
            f"row {row}, trajectory 1 (0.5 s fourier) on the nominal plant: its log, "
            f"{members[row - 1].logs[0]}. Its measured torques hold the gravity torque the "
            "robot&#x27;s own compensation adds under the command (KUKA FRI torque mode)."
        )
        assert state["ticks"] == kept.ticks
        assert np.allclose(state["error_mm"], np.linalg.norm(kept.ee - kept.ee_des, axis=1) * 1e3)
        # Each of the member's files saved from the page is `analytic export`'s, byte for byte.
        for fmt, name in FILE_NAMES.items():
            js(browser, "find(document, `a[name=export-${arguments[0]}]`).click();", fmt)
            saved = downloads / f"row{row}-{name}"
            deadline = time.monotonic() + 30
            while not saved.exists() and time.monotonic() < deadline:
                time.sleep(0.2)
            exported = analytic("export", a, "--member", str(row), "--format", fmt, cwd=tmp_path)
            assert exported.returncode == 0, exported.stderr
            assert saved.read_bytes() == exported.stdout.encode(), fmt


def read_front_json_sorted(directory: Path) -> list:
    from gainfarm.analytic.tuning.records import read_front_json, sorted_front

    return sorted_front(read_front_json(directory / "front.json"))


# What the page says of a finished run's held-out check: how the controller to use fared, or
# that the check kept the default gains.
HELD_OUT_SAID = (
    r"Held-out check( of row \d+ \(recommended\)|: no member held against the default gains)"
)


def test_a_run_says_when_it_has_no_recommendation_or_held_out_check_yet(tmp_path: Path) -> None:
    """A run stopped before its first record is stopped, not "running"; a running one has no
    recommendation before the default gains are scored (as it ends) and its check is to come."""
    from gainfarm.edges.files import Lock

    made = analytic("start", *QUICK, "--check-plants", "2", "--out", "run", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    run = tmp_path / "run"
    done = run_view(run).recommendation
    assert re.search(HELD_OUT_SAID, done) and "No recommendation yet" not in done
    for name in ("baseline.json", "check.json", "report.md"):
        (run / name).unlink()  # as the run stands before it ends
    lock = Lock(run / "run.lock")  # a process running it: this one
    try:
        live = run_view(run)
        assert live.line.endswith("; running"), live.line
        assert live.recommendation.startswith("No recommendation yet: the default gains are")
        assert live.recommendation.endswith("Held-out check: on 2 plants, once the run ends.")
    finally:
        lock.release()
    stopped = run_view(run)
    assert stopped.line.endswith("stopped: `analytic resume` continues it"), stopped.line
    assert stopped.recommendation.endswith(
        "Held-out check: not written (`analytic resume RUN` runs it)."
    )
    for name in ("history.csv", "front.json", "front.csv", "evaluated.csv"):
        (run / name).unlink()  # stopped before its first record
    assert run_view(run).line.endswith("no generation recorded; stopped: `analytic resume` "
                                       "continues it")  # fmt: skip


UR5E_JOINTS = UR5E_JOINT_NAMES


def arm_state(browser: webdriver.Chrome) -> dict:
    """The inspected run's arm as the page holds it: the table's columns and titles, the
    episode's series, the plots' legends."""
    return browser.execute_script(
        """
        const doc = Bokeh.documents[0];
        if (doc === undefined) return null;
        const named = (name) => doc.get_model_by_name(name);
        const legends = [...doc.all_models].filter((m) => m.items !== undefined && m.click_policy);
        return {
            inspect: named("inspect").value,
            members: Object.keys(named("members").data),
            titles: named("table").columns.map((column) => column.title),
            joints: Object.keys(named("episode-joints").data),
            torques: Object.keys(named("episode-torques").data),
            ticks: named("episode-joints").data.t.length,
            legends: legends.map((legend) => legend.items.map((item) => item.label.value)),
            episode: named("episode").text,
            export: named("export").text,
        };
        """
    )


def until_arm(browser: webdriver.Chrome, holds, timeout: float = 60) -> dict:
    """The page's arm (`arm_state`) once `holds` of it."""
    state = None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with contextlib.suppress(WebDriverException):
            state = arm_state(browser)
            if state is not None and holds(state):
                return state
        time.sleep(0.2)
    raise AssertionError(f"the page never got there: {json.dumps(state)[:3000]}")


@pytest.mark.slow
def test_a_ur5e_run_is_shown_with_its_six_joints(tmp_path: Path, browser) -> None:
    """A run of the UR5e (6 joints) beside one of the iiwa (7): the page shows each with its own
    arm's joints (the table's gains, the episode's lines, the exported files), and --robot
    shows only one arm's runs."""
    runs = tmp_path / "runs"
    for name, arm in (("iiwa", "iiwa14"), ("ur5e", "ur5e")):
        made = analytic("start", *QUICK, "--robot", arm, "--out", str(runs / name), cwd=tmp_path)
        assert made.returncode == 0, made.stderr
    ur5e, iiwa = str(runs / "ur5e"), str(runs / "iiwa")
    gains = [f"{gain}_{joint}" for gain in ("kp", "kd") for joint in UR5E_JOINTS]
    with dashboard(str(runs), cwd=tmp_path) as address:
        browser.get(address)
        until(browser, lambda s: sorted(s["runs"]) == sorted([ur5e, iiwa]))
        js(browser, "named('inspect').value = arguments[0];", ur5e)
        state = until_arm(
            browser, lambda s: s["inspect"] == ur5e and "kp_elbow_joint" in s["members"]
        )
        assert [name for name in state["members"] if name[:3] in ("kp_", "kd_")] == gains
        assert "kp shoulder_pan_joint" in state["titles"] and "kp A1" not in state["titles"]
        js(browser, "named('members').selected.indices = [0];")
        until(browser, lambda s: s["ticks"] > 0 and "row 1 as" in s["export"])
        state = arm_state(browser)
        assert state["joints"] == ["t", *(f"q{d}_{j}" for j in UR5E_JOINTS for d in ("", "_des"))]
        assert state["torques"] == ["t", *(f"{u}_{j}" for j in UR5E_JOINTS for u in ("u", "tau"))]
        # The angles' and the torques' legends, a line per joint; none of the iiwa's left.
        assert state["legends"].count(list(UR5E_JOINTS)) == 2
        assert not any("A1" in items for items in state["legends"])
        assert "(UR direct torque control)" in state["episode"]
        # The member's ros2_control file, as the page offers it, names the UR5e's joints.
        [encoded] = re.findall(r'name="export-ros2_control"[^>]*base64,([^"]+)"', state["export"])
        ros2 = yaml.safe_load(base64.b64decode(encoded))["pd_effort_controller"]
        assert ros2["ros__parameters"]["joints"] == list(UR5E_JOINTS)
        # And back to the iiwa: its seven joints again.
        js(browser, "named('inspect').value = arguments[0];", iiwa)
        state = until_arm(browser, lambda s: s["inspect"] == iiwa and "kp A7" in s["titles"])
        assert "kp shoulder_pan_joint" not in state["titles"]
    with dashboard(str(runs), "--robot", "ur5e", cwd=tmp_path) as address:
        browser.get(address)
        state = until(browser, lambda s: s["runs"] == [ur5e])
        assert state["inspect"] == ur5e
