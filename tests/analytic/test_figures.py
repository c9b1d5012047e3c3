"""A run's figures: whole PNGs, no crash on little data, nothing half-written."""

import struct
from pathlib import Path

import numpy as np
import pytest

from analytic.figures import plot_hypervolume, plot_pareto
from analytic.records import FrontMember
from tests.analytic.samples import KD, KP, SAMPLE_FRONT, SAMPLE_HISTORY, leftovers

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def assert_png(path: Path) -> None:
    content = path.read_bytes()
    assert content.startswith(PNG_MAGIC)
    assert 5_000 < len(content) < 2_000_000
    width, height = struct.unpack(">II", content[16:24])  # the IHDR chunk
    assert (width, height) == (840, 600)


def test_pareto_and_hypervolume_figures_are_pngs(tmp_path: Path) -> None:
    evaluated = [(m.f_acc, m.f_t) for m in SAMPLE_FRONT] + [(0.05, 1e3), (0.2, 5e5), (0.03, 2.0)]
    plot_pareto(tmp_path / "pareto.png", SAMPLE_FRONT, evaluated, title="spiral, pop 30")
    plot_hypervolume(tmp_path / "hypervolume.png", SAMPLE_HISTORY, title="spiral, pop 30")
    assert_png(tmp_path / "pareto.png")
    assert_png(tmp_path / "hypervolume.png")
    assert leftovers(tmp_path) == []


def test_figures_survive_no_data_one_generation_and_unloggable_values(tmp_path: Path) -> None:
    plot_pareto(tmp_path / "empty.png", [])
    plot_hypervolume(tmp_path / "none.png", [])
    plot_hypervolume(tmp_path / "one.png", SAMPLE_HISTORY[:1])
    odd = [FrontMember(kp=KP, kd=KD, f_acc=0.01, f_t=0.0)]
    plot_pareto(tmp_path / "odd.png", odd, [(0.02, -1.0), (float("nan"), 1.0), (0.03, np.inf)])
    plot_pareto(tmp_path / "zero.png", odd, [(0.02, 0.0)])  # nothing positive: linear axis
    for name in ("empty", "none", "one", "odd", "zero"):
        assert_png(tmp_path / f"{name}.png")


def test_a_figure_written_into_a_missing_directory_raises_and_creates_nothing(
    tmp_path: Path,
) -> None:
    missing = tmp_path / "missing"
    with pytest.raises(FileNotFoundError):
        plot_pareto(missing / "pareto.png", SAMPLE_FRONT)
    assert list(tmp_path.iterdir()) == []


def test_a_failed_figure_write_leaves_no_temporary_file(tmp_path: Path) -> None:
    # The target is a directory: the temporary file is written, then the rename fails.
    (tmp_path / "pareto.png").mkdir()
    with pytest.raises(OSError):
        plot_pareto(tmp_path / "pareto.png", SAMPLE_FRONT)
    assert leftovers(tmp_path) == [] and (tmp_path / "pareto.png").is_dir()
