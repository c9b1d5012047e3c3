"""The speed experiment at toy size, on a real local farm and in this process; and its
heatmaps' numbers, readable on every cell."""

from pathlib import Path

import numpy as np
import pytest

from gainfarm.analytic.experiments import speed
from gainfarm.analytic.experiments.measures import error_at, recommended
from gainfarm.analytic.experiments.normalisation import front_points
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.tuning.records import read_run
from tests.analytic.experiments.common import (
    BASE,
    PNG,
    in_process,
    on_farm,
    rows,
    stats_rows,
)


@pytest.mark.slow
def test_speed(tmp_path: Path, endpoints: list[str]) -> None:
    speed.run(Experiment(tmp_path, on_farm(endpoints)), BASE, reps=1, durations=[3.0, 3.5])
    results = rows(tmp_path / "results.csv")
    assert [(r["tuned_on_s"], r["evaluated_on_s"]) for r in results] == [
        ("3.0", "3.0"),
        ("3.0", "3.5"),
        ("3.5", "3.0"),
        ("3.5", "3.5"),
    ]
    for column in ("median_error_at_level_mm", "median_recommended_error_mm", "f_t_level"):
        assert all(float(r[column]) > 0 for r in results), column
    assert (tmp_path / "speed.png").read_bytes().startswith(PNG)
    assert "| 3 s |" in (tmp_path / "report.md").read_text()
    assert {r["metric"] for r in stats_rows(tmp_path)} == {
        "error_at_level_mm",
        "recommended_error_mm",
        "hypervolume",
    }


@pytest.mark.slow
def test_speed_in_process_writes_its_statistics(tmp_path: Path) -> None:
    speed.run(Experiment(tmp_path, in_process), BASE, reps=2, durations=[3.0, 3.5, 4.0])
    comparisons = {r["comparison"] for r in stats_rows(tmp_path)}
    assert "3.5 s vs 3 s, own spiral" in comparisons and "4 s vs 3.5 s, own spiral" in comparisons
    assert "tuned on 3 s vs tuned on 4 s, on 4 s" in comparisons
    report = (tmp_path / "report.md").read_text()
    assert "cannot decide whether or where the error at that smoothness levels off" in report
    assert "p Holm-adjusted over the consecutive steps of each measure" in report
    # The errors are read at one smoothness every front reaches, and of each run's pick.
    runs = [read_run(d) for d in sorted((tmp_path / "runs").iterdir())]
    level = max(min(m.f_t for m in run.front) for run in runs)
    results = {(r["tuned_on_s"], r["evaluated_on_s"]): r for r in rows(tmp_path / "results.csv")}
    assert {float(r["f_t_level"]) for r in results.values()} == {level}
    own = [run for run in runs if run.config.trajectories[0].duration == 3.0]
    at_level = [error_at(front_points(run), level) * 1000 for run in own]
    assert float(results[("3.0", "3.0")]["median_error_at_level_mm"]) == pytest.approx(
        np.median(at_level)
    )
    picked = [recommended(run).member.f_acc * 1000 for run in own]
    assert float(results[("3.0", "3.0")]["median_recommended_error_mm"]) == pytest.approx(
        np.median(picked)
    )
    assert f"Error at f_t ≤ {level:.4g} (N·m)², mm, median [95 % CI]:" in report


# --- the speed experiment's heatmaps: numbers readable on every cell -------------------------

VIRIDIS_ENDS = {"dark": (68, 1, 84), "bright": (253, 231, 37)}  # viridis at 0 and at 1, as RGB


def text_on(image: np.ndarray, rgb: tuple[int, int, int]) -> list[np.ndarray]:
    """The pixels of the text written on each large block of colour `rgb` in `image` (the
    heatmaps' cells, or several cells that touch; not the colour bar, whose ends are thin
    strips): the holes in the block."""
    from scipy import ndimage

    mask = (np.abs(image[..., :3].astype(int) - rgb) <= 12).all(axis=-1)
    labels, count = ndimage.label(mask)
    texts = []
    for label in range(1, count + 1):
        block = labels == label
        if block.sum() < 40 * 40:
            continue
        holes = ndimage.binary_fill_holes(block) & ~block
        texts.append(image[holes].astype(int))
    return texts


def test_the_speed_heatmaps_numbers_contrast_with_their_cells(tmp_path: Path) -> None:
    """Dark text on the bright (yellow) cells, white on the dark (purple) ones, read back from
    the PNG's pixels (Pillow, not matplotlib)."""
    from PIL import Image

    durations = [3.0, 4.0]
    high = {(t, u): 0.9 if (t, u) == (3.0, 3.0) else 0.1 for t in durations for u in durations}
    speed.figure(tmp_path / "speed.png", durations, high, {k: v / 100 for k, v in high.items()})
    image = np.asarray(Image.open(tmp_path / "speed.png").convert("RGB"))
    bright, dark = text_on(image, VIRIDIS_ENDS["bright"]), text_on(image, VIRIDIS_ENDS["dark"])
    assert len(bright) == 2 and len(dark) == 2  # in each panel: one bright cell, three dark
    for text in bright:
        assert (text.sum(axis=-1) < 150).sum() > 20  # the number, in black
        assert not (text.min(axis=-1) > 230).any()  # and nothing in white
    for text in dark:
        assert (text.min(axis=-1) > 230).sum() > 60  # three numbers, in white
        assert not (text.sum(axis=-1) < 60).any()  # and nothing in black


def test_the_text_colour_is_the_one_of_higher_contrast_over_the_whole_colour_map() -> None:
    from matplotlib import colormaps

    def luminance(rgb: tuple[float, ...]) -> float:
        linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in rgb[:3]]
        return 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]

    for x in np.linspace(0, 1, 101):
        background = colormaps["viridis"](x)
        text = (0.0, 0.0, 0.0) if speed.text_colour(background) == "black" else (1.0, 1.0, 1.0)
        lighter, darker = sorted((luminance(background), luminance(text)), reverse=True)
        assert (lighter + 0.05) / (darker + 0.05) >= 4.5  # WCAG AA for normal text
