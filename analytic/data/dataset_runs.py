"""Which runs and controllers a dataset takes: each run read (a run from before front.json or
run ids upgraded, given its id), one given twice refused (its episodes would share ids), and its
whole front or its knee selected."""

import contextlib
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from gainfarm.analytic.tuning.picks import knee
from gainfarm.analytic.tuning.records import (
    RUN_JSON,
    FrontMember,
    RunRecord,
    read_identity,
    read_run,
)
from gainfarm.analytic.tuning.run import RunBusy, TuningRun, upgrade
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.wire import one_line

Selection = Literal["front", "knee"]


class UnreadableRun(ValueError):
    pass


class DuplicateEpisodes(ValueError):
    """Two sources would give the same episode id: refused, never merged."""


@dataclass(frozen=True)
class ChosenRun:
    """One run and the controllers selected from it."""

    directory: Path
    name: str
    run_id: str
    plant: PlantSpec
    members: list[FrontMember]
    feedforward: str | None = None  # the learned model its episodes add to the PD, if any
    # The safety limits its config checks every episode against.
    limits: Limits = dataclasses.field(default_factory=Limits)


def select(run: RunRecord, selection: Selection) -> list[FrontMember]:
    """The front, or its knee: the member `analytic export` takes (analytic.tuning.picks)."""
    front = run.front
    if selection == "front" or not front:
        return front
    return [knee(front)]


def run_id_of(run_dir: Path) -> str:
    """The run's id from run.json. A run from between front.json and run ids has none yet:
    opening it gives it one (what its next resume would do); one that another process is
    running got it when that process opened it."""
    path = Path(run_dir) / RUN_JSON
    if not path.exists():
        with contextlib.suppress(RunBusy):
            TuningRun.open(run_dir).close()
    return read_identity(path).run_id


def choose(run_dirs: Sequence[Path], selection: Selection) -> list[ChosenRun]:
    """Each run with its selected controllers; a run given twice (or a copy of one: the same
    run_id) is refused, since its episodes would get the same ids."""
    chosen: list[ChosenRun] = []
    seen: dict[str, Path] = {}
    for run_dir in run_dirs:
        try:
            upgrade(run_dir)
            run = read_run(run_dir)
            run_id = run_id_of(run_dir)
        except (OSError, ValueError, RunBusy) as error:
            raise UnreadableRun(f"{str(run_dir)!r}: unreadable run ({one_line(error)})") from None
        if run_id in seen:
            raise DuplicateEpisodes(
                f"{str(seen[run_id])!r} and {str(run_dir)!r} are the same run (run_id {run_id}): "
                "a run given twice, or a copy of one; give each run once"
            )
        seen[run_id] = Path(run_dir)
        name = Path(run_dir).resolve().name
        members = select(run, selection)
        chosen.append(
            ChosenRun(
                Path(run_dir),
                name,
                run_id,
                run.config.plant,
                members,
                run.config.feedforward,
                run.config.limits,
            )
        )
    return chosen
