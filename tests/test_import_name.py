"""One import name: installed, the project adds `gainfarm` and nothing else to the top level, so
a researcher's folder with its own `models.py`, `schemas.py` (common next to a notebook) breaks
nothing of it."""

import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

import gainfarm

ROOT = Path(__file__).parents[1]
# A folder holding a module of each name the project installed at the top level before the move.
CLASHING = ("models", "schemas", "cli", "worker", "broker", "analytic")

# Tunes a tiny problem through gainfarm's face: real episodes, in this process, a fraction of a
# second each, so the whole import graph (worker, schemas, models, analytic) is exercised.
SCRIPT = textwrap.dedent(
    """
    import gainfarm
    from gainfarm.analytic import InProcessEvaluator
    from gainfarm.schemas import TrajectorySpec

    config = gainfarm.RunConfig(
        pop=4, generations=1, seed=3, trajectories=(TrajectorySpec(kind="fourier", duration=0.2),)
    )
    run = gainfarm.tune(config, "run", evaluator=InProcessEvaluator())
    print(len(run.front()), "members")
    """
)


@pytest.mark.slow
def test_the_wheel_installs_one_top_level_name(tmp_path: Path) -> None:
    source = tmp_path / "source"  # a copy: building writes build/ and *.egg-info beside the source
    shutil.copytree(
        ROOT,
        source,
        ignore=shutil.ignore_patterns(".*", "__pycache__", "runs", "build", "*.egg-info", "bench"),
    )
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", str(source), "-w", tmp_path],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert built.returncode == 0, built.stderr
    [wheel] = tmp_path.glob("gainfarm-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {name.split("/")[0] for name in names} == {
        "gainfarm",
        wheel.name.split("-py")[0] + ".dist-info",
    }
    # Every package of the source tree, each module of it: a folder missing from pyproject's
    # package list would install from a checkout (the editable finder maps whole folders) and
    # be missing from the wheel, hence from the image.
    for folder in ("analytic", "worker", "broker", "schemas", "models", "gainfarm"):
        for module in (ROOT / folder).rglob("*.py"):
            inside = module.relative_to(ROOT)
            wheel_path = inside if folder == "gainfarm" else Path("gainfarm") / inside
            assert str(wheel_path) in names, f"the wheel lacks {wheel_path}"
    assert "gainfarm/models/iiwa14.xml" in names  # the data files travel with their packages


@pytest.mark.slow
def test_a_folder_of_clashing_names_breaks_nothing(tmp_path: Path) -> None:
    for name in CLASHING:
        (tmp_path / f"{name}.py").write_text(f"raise ImportError('the user\\'s own {name}.py')\n")
    tuned = subprocess.run(
        [sys.executable, "-c", SCRIPT], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert tuned.returncode == 0, tuned.stderr
    assert tuned.stdout.strip().endswith("members") and (tmp_path / "run" / "front.csv").is_file()
    analytic = Path(sys.executable).with_name("analytic")
    helped = subprocess.run(
        [analytic, "--help"], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert helped.returncode == 0, helped.stderr
    assert "Usage: analytic" in helped.stdout


def test_the_face_is_the_analytic_layers() -> None:
    from gainfarm import analytic

    assert analytic.__all__ == gainfarm.__all__  # one export list
    assert {"RunConfig", "tune", "read_run", "InProcessEvaluator", "local_farm"} <= set(
        gainfarm.__all__
    )
    assert {name: getattr(gainfarm, name) for name in gainfarm.__all__} == {
        name: getattr(analytic, name) for name in gainfarm.__all__
    }
