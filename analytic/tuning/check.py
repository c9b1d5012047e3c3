"""The held-out check: how the controllers a run names fare on plants it never saw.

At the end of a run whose config holds held-out plants (`analytic start --check-plants M`, drawn
from the uncertainty ranges on another stream of the seed than the training variants), the
controller a user takes away (the recommended member, or the closest to it), the front's knee
and the default gains run every trajectory on the nominal plant and on each held-out plant:
3 (M + 1) episodes a trajectory, where the budget allows (CHECK_SHARE: at most half the run's
own episodes; the default run affords M = 64, some 40 % of its own). The rest of the
front is not checked: at some 30 members, that would be several times the run itself. Per
controller: its error on each plant against its own on the nominal one (median and worst), and on
how many plants it broke a safety limit or diverged. check.json holds it;
front.json, report.md and the exported controller carry it.
"""

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from gainfarm.analytic.evaluators.evaluator import Evaluator
from gainfarm.analytic.tuning.picks import picks
from gainfarm.analytic.tuning.records import FRONT_JSON
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.edges.files import interrupts_deferred, write_atomically
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import measures
from gainfarm.schemas.objectives import objectives

CHECK_JSON = "check.json"
# The check's episodes are at most this share of the run's own, so a short run is not made
# several times longer by its check: the budget allows the held-out plants it allows (at least
# one). The default run (400-700 evaluations) affords all 64.
CHECK_SHARE = 0.5


@dataclass(frozen=True)
class Checked:
    """One controller on the held-out plants."""

    name: str  # a pick's name, or "default gains"
    row: int | None  # its front.csv row (None: the default gains)
    kp: tuple[float, ...]
    kd: tuple[float, ...]
    nominal_f_acc: float  # m, on the nominal plant
    median_ratio: float  # median over the held-out plants of f_acc / nominal_f_acc
    worst_ratio: float  # the largest
    violations: int  # held-out plants on which an episode broke a safety limit
    diverged: int  # held-out plants on which an episode diverged or could not run


@dataclass(frozen=True)
class CheckPlan:
    """The check about to run: `episodes` in all, on `plants` held-out plants of the `asked`
    (fewer when CHECK_SHARE caps them), for `controllers` controllers."""

    episodes: int
    plants: int
    asked: int
    controllers: int


def run_check(
    run: TuningRun,
    evaluator: Evaluator,
    on_start: Callable[[CheckPlan], None] = lambda _: None,
) -> list[Checked]:
    """Run the check of `run` (open) on `evaluator` and write it down (check.json, front.json);
    none if its config holds no held-out plants, or its front is empty. `on_start` is told what
    it is about to run, before the first episode is sent."""
    plants = run.config.check_plants
    asked = len(plants)
    front = run.front()
    if not plants or not front:
        return []
    chosen = {}
    named = picks(front, run.baseline())
    for pick in [named[0], *(pick for pick in named if pick.name == "knee")]:
        chosen.setdefault(pick.member.gains, (pick.name, pick.row))
    chosen.setdefault(DEFAULT_GAINS, ("default gains", None))
    trajectories = len(run.config.trajectories)
    ran = run.state.evolution.evaluations * trajectories * (1 + len(run.config.plants))
    affordable = int(CHECK_SHARE * ran) // (len(chosen) * trajectories) - 1
    plants = plants[: max(1, affordable)]
    started = time.monotonic()
    specs = {}
    for index, gains in enumerate(chosen):
        for number, trajectory in enumerate(run.config.trajectories):
            for plant, model in enumerate((run.config.model, *plants)):
                job_id = f"check-c{index}-t{number}-h{plant}"
                specs[job_id] = EpisodeSpec(
                    gains=gains,
                    trajectory=trajectory,
                    model=model,
                    feedforward=run.config.feedforward,
                    objectives=run.config.objectives,
                )
    on_start(CheckPlan(len(specs), len(plants), asked, len(chosen)))
    evaluator.submit(specs)
    found = {evaluation.job_id: evaluation.scores for evaluation in evaluator.results()}
    checked = [
        _summary(run, index, gains, *chosen[gains], found, len(plants))
        for index, gains in enumerate(chosen)
    ]
    cost = {"episodes": len(specs), "wall_seconds": round(time.monotonic() - started, 1)}
    _write(run, checked, len(plants), asked, cost)
    return checked


def _summary(
    run: TuningRun,
    index: int,
    gains: PDGains,
    name: str,
    row: int | None,
    found: dict[str, Scores | None],
    count: int,
) -> Checked:
    config = run.config
    trajectories = range(len(config.trajectories))

    def on(plant: int) -> list[Scores | None]:
        return [found.get(f"check-c{index}-t{number}-h{plant}") for number in trajectories]

    nominal = objectives(on(0), config.objective_weights)[0]
    errors, violations, diverged = [], 0, 0
    for plant in range(1, count + 1):
        scores = on(plant)
        errors.append(objectives(scores, config.objective_weights)[0])
        if any(score is None or score.diverged for score in scores):
            diverged += 1
        elif config.limits.violated(measures(scores)):
            violations += 1
    ratios = np.asarray(errors) / nominal if nominal > 0 else np.full(count, math.inf)
    return Checked(
        name=name,
        row=row,
        kp=gains.kp,
        kd=gains.kd,
        nominal_f_acc=nominal,
        median_ratio=float(np.median(ratios)),
        worst_ratio=float(ratios.max()),
        violations=violations,
        diverged=diverged,
    )


def _write(run: TuningRun, checked: Sequence[Checked], plants: int, asked: int, cost: dict) -> None:
    # "asked": the config's held-out plants; "plants": those the budget allowed (CHECK_SHARE).
    record = {
        "plants": plants,
        "asked": asked,
        "controllers": [asdict(item) for item in checked],
        "cost": cost,
    }
    front = run.directory / FRONT_JSON
    content = json.loads(front.read_bytes())
    content["held_out"] = record
    # Both or neither: a resume runs the check again while check.json is missing.
    with interrupts_deferred():
        write_atomically(front, json.dumps(content, indent=1).encode())
        write_atomically(run.directory / CHECK_JSON, json.dumps(record, indent=1).encode())


def read_check(directory) -> dict | None:
    """check.json of the run in `directory`, or None (no check was run)."""
    path = directory / CHECK_JSON
    if not path.exists():
        return None
    try:
        return json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None
