"""A run's figures: whole PNGs, no crash on little data, nothing half-written."""

import struct
from pathlib import Path

import numpy as np
import pytest

from gainfarm.analytic.tuning.records import Baseline, FrontMember
from gainfarm.analytic.view.export import picks
from gainfarm.analytic.view.figures import pareto_figure, plot_hypervolume, plot_pareto
from gainfarm.schemas.gains import DEFAULT_GAINS
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


def marks(figure: object) -> dict[str, tuple[float, float]]:
    """Each labelled single point on a figure's axes: its legend label's first words → (x, y)."""
    [axes] = figure.axes  # type: ignore[attr-defined]
    found = {}
    for collection in axes.collections:
        offsets = collection.get_offsets()
        if len(offsets) == 1:
            found[collection.get_label().split(":")[0]] = tuple(float(v) for v in offsets[0])
    return found


def test_the_pareto_figure_marks_the_picks_and_the_default_gains(tmp_path: Path) -> None:
    front = [m for m in SAMPLE_FRONT if not m.diverged]
    chosen = picks(front)
    baseline = Baseline(DEFAULT_GAINS, f_acc=0.02, f_t=0.05, diverged=False)
    figure = pareto_figure(front, [], "spiral 5 s", chosen, baseline)
    marked = marks(figure)
    for pick in chosen:
        name = {"knee": "knee (the controller to use)", "accurate": "most accurate"}.get(
            pick.name, "smoothest"
        )
        assert marked[name] == pytest.approx((pick.member.f_acc * 1000, pick.member.f_t))
    assert marked["default gains"] == pytest.approx((20.0, 0.05))
    labels = figure.axes[0].get_legend_handles_labels()[1]
    assert any(
        label.startswith(f"knee (the controller to use): row {chosen[0].row},") for label in labels
    )
    plot_pareto(tmp_path / "pareto.png", front, [], "spiral 5 s", chosen, baseline)
    assert_png(tmp_path / "pareto.png")


def test_default_gains_that_diverged_are_named_not_drawn() -> None:
    fell = Baseline(DEFAULT_GAINS, f_acc=10.0, f_t=1e12, diverged=True)
    figure = pareto_figure(SAMPLE_FRONT, [], "", picks(SAMPLE_FRONT), fell)
    assert "default gains" not in marks(figure)
    notes = [text.get_text() for text in figure.axes[0].texts]
    assert any("default gains diverged" in note for note in notes)
    assert figure.axes[0].get_yscale() == "log"  # the penalty did not flatten the axis
    assert figure.axes[0].get_ylim()[1] < 1e6


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

    from gainfarm.analytic.view.figures import plot_speed

    durations = [3.0, 4.0]
    high = {(t, u): 0.9 if (t, u) == (3.0, 3.0) else 0.1 for t in durations for u in durations}
    plot_speed(tmp_path / "speed.png", durations, high, {k: v / 100 for k, v in high.items()})
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

    from gainfarm.analytic.view.figures import text_colour

    def luminance(rgb: tuple[float, ...]) -> float:
        linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in rgb[:3]]
        return 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]

    for x in np.linspace(0, 1, 101):
        background = colormaps["viridis"](x)
        text = (0.0, 0.0, 0.0) if text_colour(background) == "black" else (1.0, 1.0, 1.0)
        lighter, darker = sorted((luminance(background), luminance(text)), reverse=True)
        assert (lighter + 0.05) / (darker + 0.05) >= 4.5  # WCAG AA for normal text
