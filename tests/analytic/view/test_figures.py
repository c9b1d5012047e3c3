"""A run's figures: whole PNGs, no crash on little data, nothing half-written."""

import struct
from pathlib import Path

import numpy as np
import pytest

from gainfarm.analytic.tuning.records import Baseline, FrontMember
from gainfarm.analytic.view.export import picks
from gainfarm.analytic.view.figures import (
    PICK_STYLES,
    hypervolume_figure,
    pareto_figure,
    plot_hypervolume,
    plot_pareto,
)
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


def test_the_hypervolume_says_it_is_normalised_and_shows_the_default_gains_level() -> None:
    figure = hypervolume_figure(SAMPLE_HISTORY, "spiral", baseline=0.42)
    (axes,) = figure.axes
    assert axes.get_ylabel() == "hypervolume (normalised: 0 to 1)"
    assert "f_t logarithmic from 0.01 to 10⁴ (N·m)²" in figure.get_supxlabel()
    levels = [line for line in axes.get_lines() if line.get_linestyle() == "--"]
    assert [tuple(line.get_ydata()) for line in levels] == [(0.42, 0.42)]
    assert [t.get_text() for t in axes.get_legend().get_texts()] == [
        "the run's front",
        "the default gains alone",
    ]
    assert hypervolume_figure(SAMPLE_HISTORY).axes[0].get_legend() is None  # no level, no key


def test_figures_survive_no_data_one_generation_and_unloggable_values(tmp_path: Path) -> None:
    plot_pareto(tmp_path / "empty.png", [])
    plot_hypervolume(tmp_path / "none.png", [])
    plot_hypervolume(tmp_path / "one.png", SAMPLE_HISTORY[:1])
    odd = [FrontMember(kp=KP, kd=KD, objectives=(0.01, 0.0))]
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
    baseline = Baseline(DEFAULT_GAINS, objectives=(0.02, 0.05), diverged=False)
    chosen = picks(front, baseline)
    assert [p.name for p in chosen] == ["closest", "knee", "accurate", "smooth"]
    figure = pareto_figure(front, [], "spiral 5 s", chosen, baseline)
    marked = marks(figure)
    for pick in chosen:
        name = PICK_STYLES[pick.name][3]
        assert marked[name] == pytest.approx((pick.member.f_acc * 1000, pick.member.f_t))
    assert marked["default gains"] == pytest.approx((20.0, 0.05))
    labels = figure.axes[0].get_legend_handles_labels()[1]
    assert any(
        label.startswith(f"closest to dominating the defaults: row {chosen[0].row},")
        for label in labels
    )
    plot_pareto(tmp_path / "pareto.png", front, [], "spiral 5 s", chosen, baseline)
    assert_png(tmp_path / "pareto.png")


def test_the_view_is_the_front_and_what_lies_outside_it_is_counted() -> None:
    # A front from 4 to 80 mm and f_t 0.006 to 50; chattering and soft candidates far off.
    errors = np.geomspace(0.004, 0.08, 30)
    front = [
        FrontMember(kp=KP, kd=KD, objectives=(float(e), float(50 * (0.004 / e) ** 3)))
        for e in errors
    ]
    front.append(FrontMember(kp=KP, kd=KD, objectives=(0.001, 1e7), diverged=True))  # a penalty
    outliers = [(0.3, 1e5), (0.25, 3e4), (0.006, 8e4), (0.5, 0.01)]
    evaluated = [m.objectives for m in front] + [(0.02, 1.0), (0.05, 0.5)] + outliers
    baseline = Baseline(DEFAULT_GAINS, objectives=(0.0143, 2.0), diverged=False)
    figure = pareto_figure(front, evaluated, "", picks(front, baseline), baseline)
    [axes] = figure.axes
    (x_low, x_high), (y_low, y_high) = axes.get_xlim(), axes.get_ylim()
    assert axes.get_yscale() == "log"
    # The front, with a margin either side, and no more: not the outliers' 500 mm or 1e5.
    assert 0 <= x_low < 4 and 80 < x_high < 90
    assert 0.6e-2 / 3 < y_low < 0.6e-2 * 1.0 and 50 < y_high < 50 * 3
    notes = [text.get_text() for text in axes.texts]
    # The four outliers and the diverged member's penalty point lie outside the view.
    assert any("5 evaluated points outside the view" in note for note in notes), notes
    one = pareto_figure(front, [(0.02, 1.0), outliers[0]], "", picks(front, baseline), baseline)
    assert any("1 evaluated point outside the view" in t.get_text() for t in one.axes[0].texts)
    # The recommended member, the knee and the defaults lie in it, each marked.
    for x, y in marks(figure).values():
        assert x_low < x < x_high and y_low < y < y_high


def test_the_legend_counts_the_candidates_left_out_for_breaking_a_limit() -> None:
    evaluated = [m.objectives for m in SAMPLE_FRONT if not m.diverged]
    [axes] = pareto_figure(SAMPLE_FRONT, evaluated, "", infeasible=4).axes
    labels = axes.get_legend_handles_labels()[1]
    assert f"evaluated ({len(evaluated)}; 4 beyond a limit, not drawn)" in labels, labels
    [axes] = pareto_figure(SAMPLE_FRONT, evaluated, "").axes
    assert f"evaluated ({len(evaluated)})" in axes.get_legend_handles_labels()[1]


def test_picks_of_one_member_are_told_apart_and_labelled_once() -> None:
    front = [m for m in SAMPLE_FRONT if not m.diverged]
    baseline = Baseline(DEFAULT_GAINS, objectives=(0.05, 1.0), diverged=False)
    chosen = picks(front, baseline)  # both members dominate: the knee, row 1, is recommended
    assert [(p.name, p.row) for p in chosen] == [
        ("recommended", 1),
        ("knee", 1),
        ("accurate", 1),
        ("smooth", 2),
    ]
    [axes] = pareto_figure(front, [], "", chosen, baseline).axes
    at_row_1 = [
        c
        for c in axes.collections
        if c.get_label().split(":")[0]
        in {PICK_STYLES[name][3] for name in ("recommended", "knee", "accurate")}
    ]
    sizes = [float(c.get_sizes()[0]) for c in at_row_1]
    orders = [c.get_zorder() for c in at_row_1]
    # One inside the other: each larger than the next, and drawn beneath it.
    assert sizes == sorted(sizes, reverse=True) and len(set(sizes)) == 3
    assert orders == sorted(orders) and len(set(orders)) == 3
    assert sorted(text.get_text() for text in axes.texts) == ["row 1", "row 2"]


def test_default_gains_that_diverged_are_named_not_drawn() -> None:
    fell = Baseline(DEFAULT_GAINS, objectives=(10.0, 1e12), diverged=True)
    figure = pareto_figure(SAMPLE_FRONT, [], "", picks(SAMPLE_FRONT), fell)
    assert "default gains" not in marks(figure)
    notes = [text.get_text() for text in figure.axes[0].texts]
    assert any("default gains diverged" in note for note in notes)
    assert figure.axes[0].get_yscale() == "log"  # the penalty did not flatten the axis
    assert figure.axes[0].get_ylim()[1] < 1e6
