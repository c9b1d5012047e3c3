"""The benchmarks run: each in its CI-sized form, as a real subprocess, exits 0 and prints its
figures. Their values are the benchmarks' to judge (docs/performance.md), not a test's: only
that each figure is there and is a positive, finite number."""

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"
NUMBER = r"([0-9]+(?:\.[0-9]+)?)"


def bench(script: str, *options: str, timeout: float) -> subprocess.CompletedProcess[str]:
    """`python bench/SCRIPT OPTIONS`, run from bench/ as its docstring says; its exit status 0."""
    done = subprocess.run(
        [sys.executable, script, *options],
        cwd=BENCH,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert done.returncode == 0, f"{script} exited with {done.returncode}:\n{done.stderr[-3000:]}"
    return done


def positive(text: str) -> float:
    value = float(text)
    assert math.isfinite(value) and value > 0, text
    return value


def figures(pattern: str, output: str) -> list[float]:
    """Every number `pattern` (one group) finds in `output`, each positive and finite; at least
    one."""
    found = re.findall(pattern, output)
    assert found, f"no line matching {pattern!r} in:\n{output}"
    return [positive(text) for text in found]


@pytest.mark.slow
def test_episode_bench_prints_its_ratios_to_the_physics() -> None:
    done = bench("episode_bench.py", "--quick", timeout=300)
    figures(rf"{NUMBER}\s*x physics", done.stdout + done.stderr)


@pytest.mark.slow
def test_references_prints_each_arms_shares_of_its_limits() -> None:
    done = bench("references.py", "--robots", "iiwa14,ur5e", timeout=300)
    shares = figures(r"\| (?:iiwa14|ur5e) \| \w+ \| [0-9.]+ \| ([0-9.]+) \(", done.stdout)
    assert len(shares) == 8  # two arms, four kinds
    figures(rf"largest share: {NUMBER}", done.stdout)


@pytest.mark.slow
def test_encode_bench_prints_the_logs_share_of_its_episode() -> None:
    done = bench("encode_bench.py", "--quick", timeout=300)
    assert len(figures(rf"log/episode \([^)]*\): {NUMBER}", done.stdout)) == 2


@pytest.mark.slow
def test_main_job_prints_the_runs_throughput_against_the_pools() -> None:
    # Smaller than --quick: a run of two generations is all this test needs to see.
    options = ["--evaluations", "12", "--pop", "6", "--plants", "1"]
    done = bench("main_job.py", *options, timeout=300)
    figures(rf"run/pool throughput: {NUMBER}x", done.stdout)
    figures(rf"optuna/pool throughput: {NUMBER}x", done.stdout)
    figures(rf"its episodes' physics \(replayed in one C call\): {NUMBER}x", done.stdout)
    figures(rf"robust/nominal wall time \(--plants 1, same evaluations\): {NUMBER}x", done.stdout)
    table = r"^\| (run|pool|optuna|robust run) \| (\d+) \| (\S+) \| (\S+) \| (\S+) \|$"
    rows = re.findall(table, done.stdout, re.MULTILINE)
    assert [row[0] for row in rows] == ["run", "pool", "optuna", "robust run"], done.stdout
    for _, evaluations, *measured in rows:
        assert int(evaluations) > 0
        for text in measured:
            positive(text)


@pytest.mark.slow
def test_fixed_cost_prints_a_runs_start_and_end_beyond_its_episodes() -> None:
    done = bench("fixed_cost.py", "--evaluations", "8", "--pop", "4", "--repeats", "1", timeout=300)
    figures(rf"first job {NUMBER} s,", done.stdout)
    figures(rf"last episode to exit {NUMBER} s,", done.stdout)
    table = r"^\| now \| (first_job_s|tail_s|fixed_s|wall_s) \| (\S+) \| (\S+) \|"
    rows = re.findall(table, done.stdout, re.MULTILINE)
    assert [row[0] for row in rows] == ["first_job_s", "tail_s", "fixed_s", "wall_s"], done.stdout
    for _, median, fastest in rows:
        assert positive(fastest) <= positive(median)


@pytest.mark.slow
def test_scale_prints_the_plumbing_and_a_real_run() -> None:
    # The simulated workers' jobs are short (0.2 s, a sleep): the figures' shape is what is tested.
    options = ["--quick", "--json", "--workers", "16", "--ingest", "200", "--job-seconds", "0.2"]
    done = bench("scale.py", *options, "--window", "2", timeout=300)
    report = json.loads(done.stdout)
    assert "NoopWorker" in report["plumbing"]["what"]
    for run in report["plumbing"]["runs"]:
        positive(run["utilisation"])
        positive(run["results_per_s"])
    positive(report["plumbing"]["analytic_ingest_per_s"])
    kinds = [run["kind"] for run in report["real"]["runs"]]
    assert kinds[0] == "async run" and kinds[-1].startswith("experiment"), kinds
    for run in report["real"]["runs"]:
        positive(run["utilisation"])
        positive(run["evaluations_per_s"])
        positive(run["analytic_cpu_ms"])


@pytest.mark.slow
def test_calibration_prints_its_targets_on_a_hidden_arm() -> None:
    options = ["--arms", "1", "--excitations", "3", "--duration", "8", "--evaluations", "24"]
    done = bench("calibration.py", *options, timeout=600)
    figures(rf"calibrate on 3 x 8 s: {NUMBER} s", done.stdout)
    figures(rf"q simulation error, twin against nominal: {NUMBER}x", done.stdout)
    assert "delays exact: 1 of 1" in done.stdout, done.stdout
    for name in ("twin", "nominal"):
        figures(rf"tuned on the {name}: f_acc predicted {NUMBER} mm", done.stdout)
    assert len(figures(rf"on the arm {NUMBER} mm, off by", done.stdout)) == 2


@pytest.mark.slow
def test_margins_prints_each_controllers_margins_and_their_cost() -> None:
    done = bench("margins.py", "--repeats", "1", timeout=300)
    rows = re.findall(r"^(default|search top|soft|stiff|A1/A2|Kd 0\.1x)", done.stdout, re.M)
    assert len(rows) == 6, done.stdout
    figures(rf"margins cold {NUMBER} ms", done.stdout)
    figures(rf"warm {NUMBER} ms", done.stdout)
    figures(rf"one episode {NUMBER} ms", done.stdout)


@pytest.mark.slow
def test_corners_prints_each_ends_effect_and_the_designed_corners() -> None:
    done = bench("corners.py", "--trajectory", "fourier", "--duration", "0.5", timeout=300)
    ends = figures(rf"error x\s*{NUMBER} median", done.stdout)
    assert len(ends) == 2 * 11 + 2, done.stdout  # each range's two ends, then the corners
    assert "heavy" in done.stdout and "light" in done.stdout


@pytest.mark.slow
def test_advice_prints_each_seeds_advice_against_the_default_gains(tmp_path: Path) -> None:
    out = tmp_path / "advice"
    done = bench("advice.py", "--seeds", "1", "--quick", "--out", str(out), timeout=600)
    figures(rf"nominal \S+ s: {NUMBER}x", done.stdout)
    figures(rf"held out: default {NUMBER} /", done.stdout)
    assert re.search(r"recommended in [01] of 1 seeds", done.stdout), done.stdout
