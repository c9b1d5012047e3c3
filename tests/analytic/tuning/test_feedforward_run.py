"""`analytic start --feedforward`: the gains are tuned on top of a learned model, which the run
keeps and serves to its workers."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from gainfarm.models.dynamics import digest, rigid_prior, to_bytes
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.robot import IDEAL_PLANT

RIGID_IDEAL = IDEAL_PLANT.model_copy(update={"joints": "rigid"})
START = [
    sys.executable,
    "-m",
    "gainfarm.analytic",
    "start",
    "--local",
    "--pop",
    "4",
    "--generations",
    "1",
]
SHORT = ["--trajectory", "fourier", "--duration", "1", "--plant", "ideal", "--joints", "rigid"]


@pytest.mark.slow
def test_a_run_tunes_on_top_of_the_model_and_keeps_it(tmp_path: Path) -> None:
    model = tmp_path / "model.npz"
    raw = to_bytes(rigid_prior(RIGID_IDEAL))
    model.write_bytes(raw)
    run = tmp_path / "run"
    ran = subprocess.run(
        [*START, *SHORT, "--feedforward", str(model), "--out", str(run), "--no-replicate"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ran.returncode == 0, ran.stderr
    assert json.loads((run / "config.json").read_text())["feedforward"] == digest(raw)
    assert (run / "feedforward.npz").read_bytes() == raw
    logs = sorted((run / "episodes").glob("*.mcap"))
    assert logs
    assert {read_episode(log).metadata.spec.feedforward for log in logs} == {digest(raw)}
    assert f"learned feed-forward {digest(raw)[:12]}" in (run / "report.md").read_text()


@pytest.mark.slow
def test_a_bad_model_is_refused_in_one_line_before_anything_is_written(tmp_path: Path) -> None:
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"\x93NUMPY not really")
    forward = tmp_path / "forward.npz"
    forward.write_bytes(to_bytes(rigid_prior(RIGID_IDEAL, target="forward")))
    for bad, expected in [(junk, "--feedforward"), (forward, "inverse")]:
        out = tmp_path / f"run-{bad.stem}"
        ran = subprocess.run(
            [*START, *SHORT, "--feedforward", str(bad), "--out", str(out)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert ran.returncode != 0 and expected in ran.stderr, ran.stderr
        assert len(ran.stderr.strip().splitlines()) == 1 and "Traceback" not in ran.stderr
        assert not out.exists()
