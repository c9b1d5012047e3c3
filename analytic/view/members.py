"""A run's front member by member, as the dashboard shows it: the table's columns, a member's
controller files (what `analytic export` writes), and one of its episodes as series to plot.

Rows are front.csv's (most accurate first, numbered from 1), so a row named on the page is the
`--member N` of `analytic export` and the report's #. A member's episode is read from the log
the run keeps of it (front.json's `logs`, in episodes/: the run fetches the front's logs from
the workers that made them as it writes its records); one the run has not kept (its worker let
it go first, or a run that keeps none) is simulated again here, episodes being deterministic,
and the page says so. Gains and series are per joint of the run's arm, named by its joint names
(its plant's robot: `joints_of`), whatever their count.
"""

import base64
import html
import math
import threading
from collections import Counter, OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import declarations, shown_unit
from gainfarm.analytic.tuning.picks import Pick
from gainfarm.analytic.tuning.records import EPISODES, FEEDFORWARD, FrontMember, sorted_front
from gainfarm.analytic.tuning.run import slot_of
from gainfarm.analytic.view.export import (
    FORMATS,
    BadMember,
    BadRun,
    controller,
    joints_of,
    render,
)
from gainfarm.cli.words import counted
from gainfarm.models.dynamics import MAX_FILE_BYTES, feedforward_from_bytes
from gainfarm.schemas.documents import quoted, read_bounded
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.limits import MEASURED
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, decode_episode, read_episode

# The table's columns, in its order: the row, the picks it is, its scores, its gains (a Kp and a
# Kd per joint of the run's arm: `gain_columns`), its safety measures (schemas.limits), how its
# episodes were checked, and how it fared on held-out plants.
SCORES = ("f_acc_mm", "f_t")
TEXTS = ("picked", "limits", "validation", "held_out")


def gain_columns(joints: Sequence[str]) -> tuple[str, ...]:
    """The gains' columns of an arm of `joints`: kp_JOINT for each joint, then kd_JOINT."""
    return tuple(f"{gain}_{joint}" for gain in ("kp", "kd") for joint in joints)


def columns(joints: Sequence[str]) -> tuple[str, ...]:
    """The member table's columns, in its order, for a run of an arm of `joints`."""
    return ("row", *SCORES, *gain_columns(joints), *MEASURED, *TEXTS)


# The files one member's export offers: `analytic export`'s formats, each under its file name.
FILE_NAMES = {"json": "controller.json", "yaml": "controller.yaml", "ros2_control": "ros2.yaml"}


def table(
    front: Sequence[FrontMember], chosen: Sequence[Pick], config: RunConfig, check: dict | None
) -> dict[str, list]:
    """The member table's columns (`columns` of the run's arm's joints): one row per member of
    `front`, front.csv's order. `chosen`: the run's picks; `check`: its check.json (None: not
    checked)."""
    members = sorted_front(front)
    names = joints_of(config.plant, len(members[0].kp) if members else None)
    gains = gain_columns(names)
    named: dict[int, list[str]] = {}
    for pick in chosen:
        named.setdefault(pick.row, []).append(pick.name)
    checked = (check or {}).get("controllers", ())
    held = {(tuple(item["kp"]), tuple(item["kd"])): item for item in checked}
    found: dict[str, list] = {name: [] for name in columns(names)}
    for row, member in enumerate(members, start=1):
        found["row"].append(row)
        # The run's first two objectives, in their own sense and shown unit (f_acc in mm); the
        # columns keep the paper's keys, the dashboard's titles name the run's objectives.
        first, second = declarations(member.names[:2])
        found["f_acc_mm"].append(member.named[first.name] * shown_unit(first)[1])
        found["f_t"].append(member.named[second.name] * shown_unit(second)[1])
        for name, gain in zip(gains, member.kp + member.kd, strict=True):
            found[name].append(gain)
        measured = member.measures + (math.nan,) * (len(MEASURED) - len(member.measures))
        for name, value in zip(MEASURED, measured, strict=True):
            found[name].append(value)
        found["picked"].append(", ".join(named.get(row, ())))
        found["limits"].append(_limits(member, config))
        found["validation"].append(_validation(member))
        item = held.get((member.kp, member.kd))
        found["held_out"].append(held_out_text(item, check["plants"]) if item and check else "")
    return found


def _limits(member: FrontMember, config: RunConfig) -> str:
    if member.diverged:
        return "diverged"
    if not member.measures:
        return "not measured"
    broken = config.limits.violated(member.measures)
    return f"breaks {', '.join(broken)}" if broken else "within"


def _validation(member: FrontMember) -> str:
    """How the member's episodes were checked: each kind with its count, e.g. "refereed:
    agreed ×2"."""
    kinds = Counter(
        episode.check if episode.check == "not checked" else f"{episode.check}: {episode.ruling}"
        for episode in member.episodes
    )
    return "; ".join(f"{kind} ×{count}" for kind, count in sorted(kinds.items()))


def held_out_text(item: dict, plants: int) -> str:
    """A checked controller on the held-out plants, in a line: its mean error (median, worst),
    and on how many plants it broke a limit or diverged."""
    if "median_f_acc" in item:
        error = (
            f"error {item['median_f_acc'] * 1e3:.2f} mm median, "
            f"{item['worst_f_acc'] * 1e3:.2f} mm worst"
        )
    else:  # a check from before it was absolute
        error = f"error ×{item['median_ratio']:.3g} median, ×{item['worst_ratio']:.3g} worst"
    return (
        f"{error} on {counted(plants, 'plant')}; {item['violations']} broke a limit, "
        f"{item['diverged']} diverged"
    )


def robustness_text(chosen: Sequence[Pick], check: dict | None, asked: int) -> str:
    """How the controller to use fared on the held-out plants (analytic.tuning.check), beside
    the default gains, of the `asked` plants; or that the run ran no check."""
    if check is None:
        if asked:
            return "Held-out check: not written (`analytic resume RUN` runs it)."
        return "Held-out check: not run (`analytic start --check-plants M` runs one)."
    pick = chosen[0] if chosen else None
    items = check.get("controllers", ())
    default = next((i for i in items if i.get("row") is None), None)
    mine = next((i for i in items if pick is not None and i.get("row") == pick.row), None)
    plants = check["plants"]
    budget = f" (of the {asked} asked: the check's budget)" if plants < asked else ""
    if pick is not None and pick.name == "closest" and "advice" in check:
        said = "Held-out check: no member held against the default gains; keep them"
        if default is not None:
            said += f" ({held_out_text(default, plants)}){budget}"
        return said + "."
    if pick is None or mine is None:
        return "Held-out check: its controllers are no longer on the front."
    said = f"Held-out check of row {pick.row} ({pick.name}): " + held_out_text(mine, plants)
    said += budget  # the check's budget allowed fewer than the config asks for
    if default is not None:
        said += "; the default gains: " + held_out_text(default, plants)
    return said + "."


def export_links(directory: Path, row: int) -> str:
    """HTML: each of `analytic export`'s files of the member at `row`, as a link that saves it
    (the bytes are the command's own: analytic.view.export), or why it cannot be exported."""

    try:
        chosen = controller(directory, str(row))
    except (BadRun, BadMember) as error:
        return html.escape(f"row {row}: {error}")
    links = []
    for fmt in FORMATS:
        encoded = base64.b64encode(render(chosen, fmt)).decode()
        name = f"row{row}-{FILE_NAMES[fmt]}"
        links.append(
            f'<a name="export-{fmt}" download="{name}" '
            f'href="data:application/octet-stream;base64,{encoded}">{html.escape(name)}</a>'
        )
    command = f"analytic export {directory} --member {row} --format FORMAT"
    return (
        f"row {row} as {' · '.join(links)} "
        f"<span style='color:grey'>(the files of <code>{html.escape(command)}</code>)</span>"
    )


# --- one member's episode --------------------------------------------------------------------


@dataclass(frozen=True)
class Slot:
    """One of a member's episodes: a trajectory (0-based) on a plant (0: the nominal)."""

    trajectory: int
    plant: int
    path: str = field(default="", compare=False)  # the trajectory in words: "3 s spiral"

    def label(self) -> str:
        plant = "the nominal plant" if self.plant == 0 else f"plant variant {self.plant}"
        path = f" ({self.path})" if self.path else ""
        return f"trajectory {self.trajectory + 1}{path} on {plant}"


def slots(config: RunConfig) -> list[Slot]:
    """Every episode a member runs, in its job ids' order (analytic.tuning.run)."""
    return [
        Slot(trajectory, plant, f"{path.duration:g} s {path.kind}")
        for trajectory, path in enumerate(config.trajectories)
        for plant in range(1 + len(config.plants))
    ]


def _slot(log: str) -> Slot:
    """The slot of a kept log, from its name: episodes/<job id>.mcap."""
    return Slot(*slot_of(Path(log).stem))


def episode(
    directory: Path, config: RunConfig, member: FrontMember, slot: Slot
) -> tuple[EpisodeLog | None, str]:
    """The member's episode at `slot` and where it came from: its log in the run directory, or
    else simulated again here; (None, why) if neither can be had."""

    kept = {}
    for log in member.logs:
        try:
            kept[_slot(log)] = log
        except (IndexError, ValueError):  # a name of another form: not one this reads
            continue
    if slot in kept:
        path = directory / kept[slot]
        if not path.resolve().is_relative_to(Path(directory).resolve()):
            return None, f"{quoted(kept[slot])} lies outside the run: not read"
        try:
            return read_episode(path), f"its log, {kept[slot]}"
        except FileNotFoundError:
            pass  # pruned since the front was written: simulated again below
        except (OSError, NotAnEpisodeLog) as error:
            return None, f"{kept[slot]}: {error}"
    spec = config.episode_spec(member.gains, slot.trajectory, slot.plant)
    key = (str(Path(directory).resolve()), spec.model_dump_json())
    with _CACHE_LOCK:
        if key in _SIMULATED:
            _SIMULATED.move_to_end(key)
            return _SIMULATED[key]
    if not _SIMULATING.acquire(blocking=False):
        return None, BUSY
    try:
        found = _simulated(directory, spec)
    finally:
        _SIMULATING.release()
    if found[0] is not None:
        with _CACHE_LOCK:
            _SIMULATED[key] = found
            while len(_SIMULATED) > CACHED_EPISODES:
                _SIMULATED.popitem(last=False)
    return found


# The episodes simulated again, the latest used last: clicking back to a member costs nothing,
# and the cache holds a few episodes (some MB each), never one per member clicked.
CACHED_EPISODES = 8
_SIMULATED: "OrderedDict[tuple[str, str], tuple[EpisodeLog, str]]" = OrderedDict()
_CACHE_LOCK = threading.Lock()
# One simulation at a time, in the whole dashboard: a click while one runs is told so at once
# (BUSY) rather than queued, so clicking through members cannot pile up work.
_SIMULATING = threading.Lock()
BUSY = "busy simulating another episode (one at a time): pick it again in a moment"


def _simulated(directory: Path, spec: EpisodeSpec) -> tuple[EpisodeLog | None, str]:
    """The episode of `spec` simulated here, or (None, why not)."""
    from gainfarm.worker.job import simulate  # start-up: MuJoCo, only to simulate

    try:
        outcome = simulate(spec, lambda _digest: _feedforward(directory))
    except (OSError, ValueError) as error:  # the run's feed-forward model, unreadable
        return None, f"no log in {EPISODES}/, and its run's {FEEDFORWARD} cannot be read: {error}"
    if not outcome.content:
        return None, f"no log in {EPISODES}/, and it cannot be simulated here: {outcome.reason}"
    why = "simulated again here (episodes are deterministic): the run keeps no log of it"
    return decode_episode(outcome.content), why


def _feedforward(directory: Path):  # -> gainfarm.models.dynamics.DynamicsModel

    return feedforward_from_bytes(read_bounded(directory / FEEDFORWARD, MAX_FILE_BYTES))


def series(
    log: EpisodeLog, names: Sequence[str] | None = None
) -> dict[str, dict[str, list[float]]]:
    """The episode as the page plots it, against time, its arm's joints named `names` (by
    default its robot's joint names, as `joints_of` finds them): "joints"
    (each joint's angle q_JOINT and its reference q_des_JOINT, rad), "error" (the end effector's
    distance from the desired point, mm: what f_acc averages) and "torques" (each joint's
    command u_JOINT and its measured torque tau_JOINT, N·m)."""
    if names is None:
        names = joints_of(log.metadata.spec.plant, log.q.shape[1])
    t = log.t.tolist()
    joints: dict[str, list[float]] = {"t": t}
    torques: dict[str, list[float]] = {"t": t}
    for j, joint in enumerate(names):
        joints[f"q_{joint}"] = log.q[:, j].tolist()
        joints[f"q_des_{joint}"] = log.q_des[:, j].tolist()
        torques[f"u_{joint}"] = log.u[:, j].tolist()
        torques[f"tau_{joint}"] = log.tau[:, j].tolist()
    error = (np.linalg.norm(log.ee - log.ee_des, axis=1) * 1000.0).tolist()
    return {"joints": joints, "error": {"t": t, "error_mm": error}, "torques": torques}


def empty_series(names: Sequence[str]) -> dict[str, dict[str, list[float]]]:
    """`series`' columns with no point: nothing chosen, for an arm of joints `names`."""
    return {
        "joints": {"t": [], **{f"{q}_{j}": [] for q in ("q", "q_des") for j in names}},
        "error": {"t": [], "error_mm": []},
        "torques": {"t": [], **{f"{u}_{j}": [] for u in ("u", "tau") for j in names}},
    }
