import json
import subprocess
import sys
from pathlib import Path

import pytest

from schemas.mcap_episode import write_episode
from tests.helpers import analytic, crafted_log

ANALYTIC = [sys.executable, "-c", "from analytic.cli import main; main()"]


def test_evaluate_scores_a_crafted_log_from_the_file(tmp_path):
    path = tmp_path / "crafted.mcap"
    write_episode(crafted_log(), path)
    result = subprocess.run(
        [*ANALYTIC, "evaluate", str(path), "--json"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    scores = json.loads(result.stdout)
    assert abs(scores["f_acc"] - 0.7 / 3) < 1e-12
    assert abs(scores["f_t"] - 1609.0 / 3) < 1e-9


def test_evaluate_rejects_what_is_not_an_episode_log(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_text("not an mcap file")
    for target in (junk, tmp_path / "missing.mcap"):
        result = subprocess.run(
            [*ANALYTIC, "evaluate", str(target)], capture_output=True, text=True, timeout=60
        )
        assert result.returncode == 2
        assert result.stderr.startswith("analytic: error:") and result.stderr.count("\n") == 1


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (
            ["--algorithms", "nsga2,cmaes"],
            "--algorithms: unknown algorithm 'cmaes': one of nsga2, ",
        ),
        (["--algorithms", "nsga2,random,nsga2"], "--algorithms: algorithm 'nsga2' given twice"),
        (["--objective-scaling", "raw,sqrt"], "--objective-scaling: unknown objective scaling"),
        (["--generations", "3"], "--generations: the algorithms study compares on a budget"),
    ],
)
def test_the_algorithms_study_refuses_bad_options_in_one_line_before_anything_is_written(
    tmp_path: Path, arguments: list[str], message: str
) -> None:
    run = analytic("experiment", "algorithms", *arguments, "--local", "--out", "out", cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr.startswith(f"analytic: error: {message}"), run.stderr
    assert len(run.stderr.splitlines()) == 1
    assert not (tmp_path / "out").exists()
