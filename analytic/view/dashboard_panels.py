"""The dashboard's panels (analytic.view.dashboard): a run's, the runs compared, and one run
inspected, each a class holding its Bokeh models and bringing them up to date from a `RunView`.

Bokeh is the `dashboard` extra: this module imports it at its top, and is itself imported only
when the dashboard is served (analytic.view.dashboard.serve).
"""

import html
from pathlib import Path
from typing import Any

from bokeh.layouts import column, row
from bokeh.models import (
    ColumnDataSource,
    DataTable,
    Div,
    MultiChoice,
    NumberFormatter,
    Range1d,
    Select,
    TableColumn,
)
from bokeh.plotting import figure

from gainfarm.analytic.tuning.evolution import F_T_FLOOR, REFERENCE_POINT
from gainfarm.analytic.tuning.records import FrontMember
from gainfarm.analytic.view.dashboard import PAPER_AXES, RunView
from gainfarm.analytic.view.members import (
    SCORES,
    columns,
    empty_series,
    episode,
    export_links,
    gain_columns,
    series,
    slots,
)
from gainfarm.models import robot_of
from gainfarm.plugins import PluginError
from gainfarm.schemas.limits import MEASURED

WIDE = {"sizing_mode": "stretch_width"}  # the window's width, shared by a row's plots
TABLE_ROWS_SHOWN = 12  # the member table's rows in view; more scroll
TABLE_ROW_PX = 25  # a row's height in the table (Bokeh's)
NOTHING_CHOSEN = "choose a member in the table: its controller files and an episode show here"

# The lines' colours: a joint's, and a compared run's in the page's order (matplotlib's tab10,
# as the figures, then tab20's lighter ten: twenty runs before a colour comes again).
COLOURS = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
)  # fmt: skip
RUN_COLOURS = (
    *COLOURS,
    "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5",
    "#c49c94", "#f7b6d2", "#c7c7c7", "#dbdb8d", "#9edae5",
)  # fmt: skip


def _colour(k: int) -> str:
    """The colour of the k-th run compared."""
    return RUN_COLOURS[k % len(RUN_COLOURS)]


def _legend_beside(plot: Any) -> None:
    """The plot's legend to the right of its axes, where it covers no point; a click on an
    entry hides what it names."""
    legend = plot.legend[0]
    legend.click_policy = "hide"
    legend.label_text_font_size = "9pt"
    plot.add_layout(legend, "right")


class RunPanel:
    """A run's part of the page: its heading, its line, its front and its curve."""

    def __init__(self, directory: Path):
        key = str(directory)
        self.shown: object = None  # the run's version on the page
        self.line = Div(name=f"run:{key}", text="")
        self.recommendation = Div(name=f"recommendation:{key}", text="", **WIDE)
        self.history = ColumnDataSource(
            {"evaluations": [], "hypervolume": []}, name=f"history:{key}"
        )
        self.front = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"front:{key}")
        self.evaluated = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"evaluated:{key}")
        self.baseline = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"baseline:{key}")
        self.recommended = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"recommended:{key}")
        self.closest = ColumnDataSource({"f_acc_mm": [], "f_t": []}, name=f"closest:{key}")
        self.pareto = pareto = figure(
            title="front over every evaluated point",
            x_axis_label=PAPER_AXES[0],
            y_axis_label=PAPER_AXES[1],
            y_axis_type="log",
            x_range=Range1d(0, 1),
            y_range=Range1d(1e-2, 1e4),
            height=360,
            **WIDE,
        )
        pareto.scatter("f_acc_mm", "f_t", source=self.evaluated, size=4, color="lightgrey")
        pareto.step("f_acc_mm", "f_t", source=self.front, mode="after", color="crimson")
        pareto.scatter("f_acc_mm", "f_t", source=self.front, size=6, color="crimson")
        pareto.scatter(
            "f_acc_mm", "f_t", source=self.recommended, size=18, marker="star",
            color="gold", line_color="black", legend_label="recommended (use this)",
        )  # fmt: skip
        pareto.scatter(
            "f_acc_mm", "f_t", source=self.closest, size=14, marker="plus",
            color="darkorange", line_color="black",
            legend_label="none recommended: closest to the defaults",
        )  # fmt: skip
        pareto.scatter(
            "f_acc_mm", "f_t", source=self.baseline, size=12, marker="x", color="black",
            line_width=2, legend_label="default gains",
        )  # fmt: skip
        # Below the axes, across: beside them, the long names would squeeze the front.
        self.marks = pareto.legend[0].items  # recommended, closest, default gains
        pareto.legend[0].orientation = "horizontal"
        pareto.add_layout(pareto.legend[0], "below")
        curve = figure(
            title="hypervolume (normalised: 0 to 1)",
            x_axis_label="evaluations",
            y_axis_label="hypervolume",
            height=360,
            **WIDE,
        )
        curve.line("evaluations", "hypervolume", source=self.history, line_width=2)
        curve.scatter("evaluations", "hypervolume", source=self.history, size=5)
        heading = Div(text=f"<h3>{html.escape(key)}</h3>")
        self.layout = column(
            heading, self.line, self.recommendation, row(pareto, curve, **WIDE), **WIDE
        )

    def show(self, version: object, view: RunView) -> None:
        if version != self.shown:
            self.line.text = html.escape(view.line)
            self.recommendation.text = html.escape(view.recommendation)
            if view.view is not None:  # framed as pareto.png is: the front, not the cloud
                x_low, x_high, y_low, y_high = view.view
                self.pareto.x_range.update(start=x_low, end=x_high)
                self.pareto.y_range.update(start=y_low, end=y_high)
            outside = f" ({view.outside} outside the view)" if view.outside else ""
            self.pareto.title.text = f"front over every evaluated point{outside}"
            self.pareto.xaxis.axis_label, self.pareto.yaxis.axis_label = view.axes
            self.closest.data = view.closest
            for item, points in zip(
                self.marks, (view.recommended, view.closest, view.baseline), strict=True
            ):
                item.visible = bool(points["f_acc_mm"])  # no entry for what is not drawn
            self.history.data = view.history
            self.front.data = view.front
            self.evaluated.data = view.evaluated
            self.baseline.data = view.baseline
            self.recommended.data = view.recommended
            self.shown = version


class Compare:
    """The chosen runs side by side: their hypervolume curves and their fronts, each in the
    hypervolume's normalised space, so that runs of other populations and budgets compare.
    Every run is chosen as it appears; one taken out of the choice stays out."""

    def __init__(self) -> None:
        self.choice = MultiChoice(name="chosen-runs", title="runs compared", **WIDE)
        self.overlay = ColumnDataSource(
            {"xs": [], "ys": [], "run": [], "colour": []}, name="overlay"
        )
        self.fronts = ColumnDataSource({"xs": [], "ys": [], "run": [], "colour": []}, name="fronts")
        self.points = ColumnDataSource({"x": [], "y": [], "colour": []}, name="front-points")
        curves = figure(
            title="hypervolume (normalised: 0 to 1) against evaluations",
            x_axis_label="evaluations",
            y_axis_label="hypervolume",
            height=320,
            **WIDE,
        )
        curves.multi_line(
            "xs", "ys", source=self.overlay, line_color="colour", line_width=2,
            legend_field="run",
        )  # fmt: skip
        _legend_beside(curves)
        fronts = figure(
            title=(
                f"fronts in the hypervolume's space: f_acc / {REFERENCE_POINT[0] * 1000:g} "
                f"mm, log f_t ({F_T_FLOOR:g} → 0, {REFERENCE_POINT[1]:g} → 1)"
            ),
            x_axis_label=f"f_acc / {REFERENCE_POINT[0] * 1000:g} mm",
            y_axis_label="log f_t (normalised)",
            height=320,
            **WIDE,
        )
        fronts.multi_line(
            "xs", "ys", source=self.fronts, line_color="colour", line_width=2,
            legend_field="run",
        )  # fmt: skip
        fronts.scatter("x", "y", source=self.points, color="colour", size=5)
        _legend_beside(fronts)
        self.layout = column(self.choice, row(curves, fronts, **WIDE), **WIDE)
        self.known: list[str] = []
        self.shown: object = None
        self.found: list[tuple[Path, object, RunView]] = []
        self.choice.on_change("value", lambda _attr, _old, _new: self.draw())

    def show(self, found: list[tuple[Path, object, RunView]]) -> None:
        self.found = found
        names = [str(directory) for directory, _, _ in found]
        new = [name for name in names if name not in self.known]
        self.known += new
        if self.choice.options != names:
            self.choice.options = names
        if new:
            self.choice.value = [*self.choice.value, *new]  # draws, through on_change
        self.draw()

    def draw(self) -> None:
        chosen = set(self.choice.value)
        shown = [
            (k, directory, view)
            for k, (directory, _, view) in enumerate(self.found)
            if str(directory) in chosen
        ]
        version = [(directory, v) for directory, v, _ in self.found if str(directory) in chosen]
        if version == self.shown:
            return
        self.shown = version
        curves = [(k, d, v) for k, d, v in shown if v.history["evaluations"]]
        self.overlay.data = {
            "xs": [view.history["evaluations"] for _, _, view in curves],
            "ys": [view.history["hypervolume"] for _, _, view in curves],
            "run": [str(directory) for _, directory, _ in curves],
            "colour": [_colour(k) for k, _, _ in curves],
        }
        fronts = [(k, d, v) for k, d, v in shown if v.normalised["x"]]
        self.fronts.data = {
            "xs": [view.normalised["x"] for _, _, view in fronts],
            "ys": [view.normalised["y"] for _, _, view in fronts],
            "run": [str(directory) for _, directory, _ in fronts],
            "colour": [_colour(k) for k, _, _ in fronts],
        }
        self.points.data = {
            "x": [x for _, _, view in fronts for x in view.normalised["x"]],
            "y": [y for _, _, view in fronts for y in view.normalised["y"]],
            "colour": [_colour(k) for k, _, view in fronts for _ in view.normalised["x"]],
        }


class Inspector:
    """One run looked into: its recommendation, its members in a sortable table, and the member
    chosen there: its controller files and one of its episodes, plotted."""

    def __init__(self) -> None:
        self.run: Path | None = None
        self.view: RunView | None = None
        self.shown: object = None
        self.chosen: FrontMember | None = None
        self.drawn: tuple[Path, FrontMember, int] | None = None  # run, member, row shown
        self.found: dict[str, tuple[object, RunView]] = {}  # every run: version, view
        self.choice = Select(name="inspect", title="run inspected", options=[], value="")
        self.recommendation = Div(name="recommendation", text="", **WIDE)
        # Until a run is inspected, no arm: no gains' columns, no joints' lines.
        self.joints: tuple[str, ...] = ()
        self.members = ColumnDataSource({name: [] for name in columns(())}, name="members")
        self.table = DataTable(
            name="table",
            source=self.members,
            columns=table_columns(()),
            sortable=True,
            selectable=True,
            index_position=None,
            autosize_mode="none",
            height=TABLE_ROWS_SHOWN * TABLE_ROW_PX + TABLE_ROW_PX,
            **WIDE,
        )
        self.export = Div(name="export", text=NOTHING_CHOSEN, **WIDE)
        self.episode_choice = Select(name="episode-choice", title="episode", options=[])
        self.episode = Div(name="episode", text="", **WIDE)
        empty = empty_series(())
        self.angles = ColumnDataSource(empty["joints"], name="episode-joints")
        self.error = ColumnDataSource(empty["error"], name="episode-error")
        self.torques = ColumnDataSource(empty["torques"], name="episode-torques")
        error = figure(
            title="tracking error: distance from the desired point",
            x_axis_label="time (s)",
            y_axis_label="mm",
            height=300,
            **WIDE,
        )
        error.line("t", "error_mm", source=self.error, line_width=2)
        self.error_plot = error
        self.plots = row(*self._joint_plots(()), **WIDE)
        self.layout = column(
            self.choice, self.recommendation, self.table, self.export, self.episode_choice,
            self.episode, self.plots, **WIDE,
        )  # fmt: skip
        self.choice.on_change("value", lambda _attr, _old, _new: self.refresh())
        self.members.selected.on_change("indices", lambda _attr, _old, _new: self.pick())
        self.episode_choice.on_change("value", lambda _attr, _old, _new: self.plot())

    def _joint_plots(self, joints: tuple[str, ...]) -> list[Any]:
        """The episode's plots for an arm of `joints`: its angles, the error, its torques; a
        line per joint (made anew when an arm of other joints is inspected)."""
        angles = figure(
            title="joint angles: measured (solid), reference (dashed)",
            x_axis_label="time (s)",
            y_axis_label="rad",
            height=300,
            **WIDE,
        )
        torques = figure(
            title="torques: command (solid), measured (dashed)",
            x_axis_label="time (s)",
            y_axis_label="N·m",
            height=300,
            **WIDE,
        )
        for j, joint in enumerate(joints):
            solid = {"color": COLOURS[j % len(COLOURS)], "legend_label": joint}
            dashed = {**solid, "line_dash": "dashed"}  # one legend entry hides both
            angles.line("t", f"q_{joint}", source=self.angles, **solid)
            angles.line("t", f"q_des_{joint}", source=self.angles, **dashed)
            torques.line("t", f"u_{joint}", source=self.torques, **solid)
            torques.line("t", f"tau_{joint}", source=self.torques, **dashed)
        for plot in (angles, torques):
            if plot.legend:  # none before an arm is inspected
                _legend_beside(plot)
        return [angles, self.error_plot, torques]

    def _arm(self, joints: tuple[str, ...]) -> None:
        """The table's gains and the episode's lines for the inspected run's arm, `joints`."""
        if joints == self.joints:
            return
        self.joints = joints
        self.table.columns = table_columns(joints)
        empty = empty_series(joints)
        self.angles.data, self.torques.data = empty["joints"], empty["torques"]
        self.plots.children = self._joint_plots(joints)

    def show(self, found: list[tuple[Path, object, RunView]]) -> None:
        names = [str(directory) for directory, _, _ in found]
        if self.choice.options != names:
            self.choice.options = names
        if self.choice.value not in names and names:
            self.choice.value = names[0]  # the run at the top: running, or the newest
        self.found = {str(directory): (version, view) for directory, version, view in found}
        self.refresh()

    def refresh(self) -> None:
        version, view = self.found.get(self.choice.value, (None, None))
        if view is None or (self.choice.value, version) == self.shown:
            return
        if self.run != Path(self.choice.value):
            self.chosen = None
        self.run, self.view = Path(self.choice.value), view
        self.shown = (self.choice.value, version)
        self.recommendation.text = html.escape(view.recommendation)
        self._arm(view.joints)
        self.members.data = view.table
        titles = dict(zip(SCORES, view.titles, strict=True))  # the run's objectives
        for item in self.table.columns:
            item.title = titles.get(item.field, item.title)
        # As tall as its rows, up to TABLE_ROWS_SHOWN (then it scrolls): no blank below.
        shown = min(max(len(view.members), 1), TABLE_ROWS_SHOWN)
        self.table.height = (shown + 1) * TABLE_ROW_PX + TABLE_ROW_PX // 2
        # The member chosen stays chosen while it is on the front (its row may move).
        keep = [i for i, m in enumerate(view.members) if m == self.chosen]
        if self.members.selected.indices != keep:
            self.members.selected.indices = keep  # picks again, through on_change
        else:
            self.pick()

    def pick(self) -> None:
        view, indices = self.view, self.members.selected.indices
        if view is None or self.run is None or not indices or indices[0] >= len(view.members):
            self.chosen = self.drawn = None
            self.export.text = NOTHING_CHOSEN
            self.episode_choice.options, self.episode.text = [], ""
            for source, empty in self._episode_sources():
                source.data = empty
            return
        member = view.members[indices[0]]
        if (self.run, member, indices[0] + 1) == self.drawn:
            return  # the same member at the same row, drawn already
        self.chosen, self.drawn = member, (self.run, member, indices[0] + 1)
        self.export.text = export_links(self.run, indices[0] + 1)
        assert view.config is not None  # a run with members has its config
        labels = [slot.label() for slot in slots(view.config)]
        if self.episode_choice.options != labels:
            self.episode_choice.options = labels
        if self.episode_choice.value != labels[0]:
            self.episode_choice.value = labels[0]  # plots, through on_change
        else:
            self.plot()

    def plot(self) -> None:
        view, member = self.view, self.chosen
        if view is None or view.config is None or member is None or self.run is None:
            return
        labels = [slot.label() for slot in slots(view.config)]
        if self.episode_choice.value not in labels:
            return
        slot = slots(view.config)[labels.index(self.episode_choice.value)]
        found, where = episode(self.run, view.config, member, slot)
        row_number = view.members.index(member) + 1
        said = f"row {row_number}, {slot.label()}: {where}."
        if view.config.plant.interface == "fri":  # what the dashed torques hold
            said += (
                " Its measured torques hold the gravity torque the robot's own "
                f"compensation adds under the command ({_interface(view)})."
            )
        self.episode.text = html.escape(said)
        drawn = series(found, view.joints) if found is not None else empty_series(view.joints)
        for (source, _), name in zip(
            self._episode_sources(), ("joints", "error", "torques"), strict=True
        ):
            source.data = drawn[name]

    def _episode_sources(self) -> list[tuple[Any, dict]]:
        empty = empty_series(self.joints)
        return [
            (self.angles, empty["joints"]),
            (self.error, empty["error"]),
            (self.torques, empty["torques"]),
        ]


def _interface(view: RunView) -> str:
    """The run's arm's torque interface by its maker's name (FRI torque mode, the iiwa's)."""
    assert view.config is not None
    try:
        return robot_of(view.config.plant).torque_interface.name
    except PluginError:
        return f"{view.config.plant.robot}'s torque interface"


def table_columns(joints: tuple[str, ...]) -> list[TableColumn]:
    """The member table's columns for a run of an arm of `joints`, each sortable."""

    def numeric(field: str, title: str, fmt: str, width: int = 70) -> TableColumn:
        return TableColumn(
            field=field, title=title, formatter=NumberFormatter(format=fmt), width=width
        )

    # Widths that hold their headers and values whole (the table scrolls sideways); a measure's
    # title is its name's first word ("saturated", for saturated_fraction).
    gains = gain_columns(joints)
    return [
        TableColumn(field="row", title="row", width=45),
        TableColumn(field="picked", title="picked", width=170),
        numeric("f_acc_mm", "f_acc (mm)", "0.000", 95),
        numeric("f_t", "f_t ((N·m)²)", "0.0000", 105),
        *(numeric(name, _title(name), "0", _width(name, 70)) for name in gains[: len(joints)]),
        *(numeric(name, _title(name), "0.00", _width(name, 65)) for name in gains[len(joints) :]),
        *(numeric(name, name.split("_")[0], "0.000", 90) for name in MEASURED),
        TableColumn(field="limits", title="limits", width=110),
        TableColumn(field="validation", title="validation", width=200),
        TableColumn(field="held_out", title="held-out plants", width=520),
    ]


def _title(gain: str) -> str:
    """A gain's column title: "kp A1", "kd shoulder_pan_joint"."""
    return gain.replace("_", " ", 1)


def _width(gain: str, least: int) -> int:
    """A gain's column width, px: its title whole (some 7 px a character), at least `least`."""
    return max(least, 7 * len(_title(gain)) + 10)
