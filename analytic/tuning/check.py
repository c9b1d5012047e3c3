"""The held-out check: how the controllers a run names fare on plants it never saw, and the
advice it gives.

At the end of a run whose config holds held-out plants (`analytic start --check-plants M`, drawn
from the uncertainty ranges on another stream of the seed than the training variants), the
candidates to recommend (the members that dominate the default gains as the run scored them, in
the knee's order), the front's knee and the default gains run every trajectory on the nominal
plant and on each held-out plant: the first candidate, the knee and the defaults in one round,
then two candidates a round until one holds (`failures`), within CHECK_SHARE (at most half the
run's own episodes). Per controller, in absolute terms: its objectives on the nominal plant, the
median and the worst of its error over the held-out plants, on which plants it broke a safety
limit or diverged, and its closed loop's margins on the nominal plant (worker.stability). The
first candidate that holds is the controller to use (the advice); if none does, the default
gains are. check.json holds it; front.json, report.md and the exported controller carry it.

On a farm not its own the run's referee (analytic.evaluators.replication) runs again, before any
candidate is judged to hold, every episode of the default gains and of each candidate that holds
on the figures so far, every failure a worker claims, a spot-checked share at the run's rate, and
every episode a caught worker ran: the advice is decided on figures the referee agreed with or
replaced (`_Check`).
"""

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus, Evaluator
from gainfarm.analytic.evaluators.replication import (
    Check,
    claims_failure,
    spot_checked,
    validate,
)
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.picks import (
    Advice,
    closest_index,
    dominates,
    knee_index,
    ranked_dominating,
)
from gainfarm.analytic.tuning.records import (
    FRONT_JSON,
    Baseline,
    FrontMember,
    read_record,
    sorted_front,
)
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.cli.words import counted
from gainfarm.edges.files import interrupts_deferred, write_atomically
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.limits import measures
from gainfarm.schemas.objectives import objectives
from gainfarm.schemas.robot import PlantSpec

CHECK_JSON = "check.json"
# The check's episodes are at most this share of the run's own, so a short run is not made
# several times longer by its check: the budget allows the held-out plants it allows (at least
# one). The default run (400-700 evaluations) affords all 64.
CHECK_SHARE = 0.5


@dataclass(frozen=True)
class Checked:
    """One controller on the nominal plant and the held-out plants, in absolute terms: a ratio to
    its own nominal error would reward a controller for being worse on the nominal plant."""

    name: str  # a pick's name, a candidate's ("candidate"), or "default gains"
    row: int | None  # its front.csv row (None: the default gains)
    kp: tuple[float, ...]
    kd: tuple[float, ...]
    nominal_f_acc: float  # m, on the nominal plant (the run's objectives over its trajectories)
    nominal_f_t: float  # the second objective there
    nominal_failed: bool  # an episode on the nominal plant diverged or could not run
    nominal_lag: float  # rad: its worst joint's RMS lag behind the reference there (Scores.lag)
    median_f_acc: float  # m, the median over the held-out plants
    worst_f_acc: float  # m, the largest
    violations: int  # held-out plants on which an episode broke a safety limit
    diverged: int  # held-out plants on which an episode diverged or could not run
    failed_on: tuple[int, ...] = ()  # those plants, 1-based in check_plants' order
    margins: dict | None = None  # its closed loop's margins on the nominal plant (_margins)
    failed: tuple[str, ...] = ()  # why it is not the controller to use (none: it may be)


@dataclass(frozen=True)
class CheckPlan:
    """The check about to run: `episodes` in its first round, on `plants` held-out plants of the
    `asked` (fewer when CHECK_SHARE caps them), for `controllers` controllers."""

    episodes: int
    plants: int
    asked: int
    controllers: int


# At most this many members that dominate the default gains on the run's own plants are
# checked, in the knee's order, until one holds: the first with the knee and the defaults, then
# two a round (the episodes of a round run together on the farm).
CANDIDATES = 6
# A damping ratio this much below the default gains' is as damped as theirs: a thousandth of
# critical damping is no difference a control engineer reads (report.md shows three decimals),
# and a member that keeps the default gains on the joint whose mode is least damped differs
# from them by that much through the other joints' coupling (0.0626 against 0.0635, measured).
DAMPING_TOLERANCE = 1e-3
ROUND = 2


def run_check(
    run: TuningRun,
    evaluator: Evaluator,
    on_start: Callable[[CheckPlan], None] = lambda _: None,
) -> list[Checked]:
    """Run the check of `run` (open) on `evaluator` and write it down (check.json, front.json);
    none if its config holds no held-out plants, or its front is empty. `on_start` is told what
    it is about to run, before the first episode is sent.

    The advice comes from it: the members that dominate the default gains as the run scored them
    are checked in the knee's order, with the knee and the default gains, until one holds on the
    held-out plants as `failures` asks (at most CANDIDATES, within CHECK_SHARE); the first that
    holds is the controller to use, and if none does, the default gains are."""
    while True:
        checked = _check(run, evaluator, on_start)
        # A worker caught in the check may have steered the evolution too: it runs again
        # without that worker's results, and so does the check, on the front it then finds.
        if not run.replay_without_caught(evaluator):
            return checked


def _check(
    run: TuningRun, evaluator: Evaluator, on_start: Callable[[CheckPlan], None]
) -> list[Checked]:
    """`run_check`'s one pass: the check of the run's front as it stands."""
    plants = run.config.check_plants
    asked = len(plants)
    front = sorted_front(run.front())
    if not plants or not front:
        return []
    baseline = run.baseline()
    defaults = run.config.default_gains  # the robot's
    ranked = _candidates(front, baseline, defaults)
    first = {}
    for index in ranked[:1]:
        first.setdefault(front[index].gains, ("candidate", index + 1))
    knee = knee_index(front)
    first.setdefault(front[knee].gains, ("knee", knee + 1))
    first[defaults] = ("default gains", None)  # a member that is them is checked as them
    trajectories = len(run.config.trajectories)
    ran = run.state.evolution.evaluations * trajectories * (1 + len(run.config.plants))
    budget = int(CHECK_SHARE * ran)
    affordable = budget // (len(first) * trajectories) - 1
    plants = plants[: max(1, affordable)]
    per_controller = (1 + len(plants)) * trajectories
    started = time.monotonic()
    on_start(CheckPlan(len(first) * per_controller, len(plants), asked, len(first)))
    check = _Check(run, evaluator, plants)
    check.round(first)
    spent, queue = len(first) * per_controller, ranked[1:CANDIDATES]
    while not _holding(check.checked) and queue and spent + ROUND * per_controller <= budget:
        batch = {front[i].gains: ("candidate", i + 1) for i in queue[:ROUND]}
        queue = queue[ROUND:]
        check.round(batch)
        spent += len(batch) * per_controller
    checked = _judged(check.checked)
    cost = {"episodes": spent, "wall_seconds": round(time.monotonic() - started, 1)}
    _write(run, checked, len(plants), asked, cost)
    if check.referee is not None:  # the ledger's held-out count, in the records too
        with interrupts_deferred():
            run.write_records()
    return checked


class _Check:
    """The check's rounds so far: each controller's episodes (`results`, by job id) and
    summaries (`checked`), refereed as `_refereed` says before a candidate is judged."""

    def __init__(self, run: TuningRun, evaluator: Evaluator, plants: Sequence[PlantSpec]):
        self.run, self.evaluator, self.plants = run, evaluator, plants
        self.referee = run.referee_for(evaluator)
        self.results: dict[str, EpisodeResult] = {}
        self.chosen: list[tuple[PDGains, str, int | None]] = []
        self.checked: list[Checked] = []
        self.refereed: set[str] = set()

    def round(self, chosen: dict[PDGains, tuple[str, int | None]]) -> None:
        """Run `chosen` controllers on the nominal plant and the plants, every trajectory; then
        referee what `_refereed` asks."""
        offset = len(self.chosen)
        self.chosen += [(gains, *chosen[gains]) for gains in chosen]
        self.results.update(_round(self.run, self.evaluator, list(chosen), self.plants, offset))
        self.checked += [self._summary(index) for index in range(offset, len(self.chosen))]
        self._refereed()

    def _summary(self, index: int) -> Checked:
        found = {job_id: result.scores for job_id, result in self.results.items()}
        gains, name, row = self.chosen[index]
        return _summary(self.run, index, gains, name, row, found, len(self.plants))

    def _refereed(self) -> None:
        """On a farm not its own, the referee runs the episodes the advice rests on: the default
        gains', each holding candidate's (on the figures so far), the failures workers claim,
        the spot checks' share, and every episode of a worker caught lying. A contradicted
        episode takes the referee's figures and its controller is summed up again, which can
        change what holds: so again, until nothing is left to run."""
        if self.referee is None:
            return
        while True:
            wanted = [self.results[job_id] for job_id in self._wanted()]
            if not wanted:
                return
            self.refereed.update(e.job_id for e in wanted)
            validation = validate(
                self.evaluator,
                wanted,
                self.run.state.ledger,
                referee=self.referee,
                check=Check.held_out,
            )
            for job_id in validation.unsettled:  # the referee cannot run it: it fails
                self.results[job_id] = replace(
                    self.results[job_id], status=EpisodeStatus.failed, scores=None, digest=None
                )
            self.results.update(validation.standing)
            self.run.drop_refereed_logs(validation.standing.values())
            for index in {_index_of(job_id) for job_id in validation.rulings}:
                self.checked[index] = self._summary(index)

    def _wanted(self) -> list[str]:
        """The episodes not yet refereed that `_refereed` runs now."""
        default = next((item for item in self.checked if item.row is None), None)
        holding = {
            index
            for index, item in enumerate(self.checked)
            if item.row is None
            or (item.name == "candidate" and default is not None and not failures(item, default))
        }
        caught = set(self.run.state.ledger.dissenters)
        rate, key = self.run.state.spot_rate or 0.0, self.run.state.spot_key
        return [
            job_id
            for job_id, result in self.results.items()
            if job_id not in self.refereed
            and (result.digest or claims_failure(result))
            and (
                _index_of(job_id) in holding
                or claims_failure(result)
                or result.worker in caught
                or (rate and spot_checked(key, job_id, rate))
            )
        ]


def _index_of(job_id: str) -> int:
    """The controller's index of a check's job id (`_job_id`)."""
    return int(job_id.split("check-c", 1)[1].split("-", 1)[0])


def _job_id(run: TuningRun, index: int, number: int, plant: int) -> str:
    """A check's episode: controller `index`, trajectory `number`, on `plant` (0: nominal);
    after a rewind with the run's new prefix, so no job of an earlier check is named again."""
    return f"{run.job_prefix()}check-c{index}-t{number}-h{plant}"


def _candidates(
    front: Sequence[FrontMember], baseline: Baseline | None, defaults: PDGains
) -> list[int]:
    """The indices of the sorted `front` that may be recommended, best first: those that
    dominate the robot's default gains (`defaults`) as the run scored them, in the knee's order
    (picks); the member closest to dominating them alone if none does, so that the check says
    how far it is."""
    if baseline is None:
        return [knee_index(front)]
    ranked = ranked_dominating(front, baseline) or [closest_index(front, baseline)]
    # NSGA-II starts from the default gains: a member that is them (to the decision space's
    # rounding) is no candidate to replace them.
    return [i for i in ranked if not _are_the_defaults(front[i].gains, defaults)]


def _are_the_defaults(gains: PDGains, defaults: PDGains) -> bool:
    mine = np.array(gains.kp + gains.kd)
    return bool(np.allclose(mine, defaults.kp + defaults.kd, rtol=1e-9, atol=0))


def _round(
    run: TuningRun,
    evaluator: Evaluator,
    chosen: Sequence[PDGains],
    plants: Sequence[PlantSpec],
    offset: int,
) -> dict[str, EpisodeResult]:
    """Run `chosen` controllers on the nominal plant and `plants`, every trajectory."""
    specs = {}
    for index, gains in enumerate(chosen, start=offset):
        for number, trajectory in enumerate(run.config.trajectories):
            for plant, model in enumerate((run.config.plant, *plants)):
                specs[_job_id(run, index, number, plant)] = EpisodeSpec(
                    gains=gains,
                    trajectory=trajectory,
                    plant=model,
                    feedforward=run.config.feedforward,
                    objectives=run.config.objectives,
                )
    evaluator.submit(specs)
    return {result.job_id: result for result in evaluator.results()}


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
        return [found.get(_job_id(run, index, number, plant)) for number in trajectories]

    nominal_scores = on(0)
    nominal = objectives(nominal_scores, config.objective_weights)
    errors, violations, diverged, failed_on = [], 0, 0, []
    for plant in range(1, count + 1):
        scores = on(plant)
        errors.append(objectives(scores, config.objective_weights)[0])
        if any(score is None or score.diverged for score in scores):
            diverged += 1
            failed_on.append(plant)
        elif config.limits.violated(measures(scores)):
            violations += 1
            failed_on.append(plant)
    return Checked(
        name=name,
        row=row,
        kp=gains.kp,
        kd=gains.kd,
        nominal_f_acc=nominal[0],
        nominal_f_t=nominal[1],
        nominal_failed=any(score is None or score.diverged for score in nominal_scores),
        nominal_lag=max((score.lag for score in nominal_scores if score is not None), default=0),
        median_f_acc=float(np.median(errors)),
        worst_f_acc=float(np.max(errors)),
        violations=violations,
        diverged=diverged,
        failed_on=tuple(failed_on),
        margins=_margins(config, gains),
    )


def failures(item: Checked, default: Checked) -> tuple[str, ...]:
    """Why `item` is not a controller to use in place of the `default` gains, in words (none:
    it is): it must dominate them on the nominal plant and lag no more on any joint there (the
    flange's position error does not see the wrist: a tool would roll off its path), be at most
    as far off as they are on the held-out plants (median and worst), break no limit and diverge
    on no held-out plant on which they keep to the limits (where the factory gains break one
    too, so may it: requiring more would leave the defaults to be advised, which fail the same
    test), and its tracking modes be as damped as theirs with the command late
    (`_margin_failures`)."""
    mm = 1e3
    why = []
    if item.nominal_failed:
        why.append("failed on the nominal plant")
    elif not default.nominal_failed and not dominates(
        (item.nominal_f_acc, item.nominal_f_t), (default.nominal_f_acc, default.nominal_f_t)
    ):
        why.append("does not dominate the default gains on the nominal plant")
    if item.nominal_lag > default.nominal_lag:  # the flange's error does not see the wrist
        why.append(
            f"a joint lags by {item.nominal_lag * 1e3:.1f} mrad RMS on the nominal plant > "
            f"{default.nominal_lag * 1e3:.1f}"
        )
    if item.median_f_acc > default.median_f_acc:
        why.append(
            f"median held-out error {item.median_f_acc * mm:.2f} mm > "
            f"{default.median_f_acc * mm:.2f}"
        )
    if item.worst_f_acc > default.worst_f_acc:
        why.append(
            f"worst held-out error {item.worst_f_acc * mm:.2f} mm > {default.worst_f_acc * mm:.2f}"
        )
    theirs = set(default.failed_on)
    broke = [plant for plant in item.failed_on if plant not in theirs]
    if broke:
        why.append(
            f"broke a limit or diverged on {counted(len(broke), 'held-out plant')} the default "
            "gains keep to"
        )
    why += _margin_failures(item.margins, default.margins)
    return tuple(why)


def _holding(checked: Sequence[Checked]) -> bool:
    """Whether a checked candidate holds against the default gains."""
    default = next((item for item in checked if item.row is None), None)
    return default is not None and any(
        item.row is not None and item.name == "candidate" and not failures(item, default)
        for item in checked
    )


def _judged(checked: list[Checked]) -> list[Checked]:
    """`checked` with each member's failures said; the first candidate that holds (the knee's
    order) named "recommended"."""
    default = next(item for item in checked if item.row is None)
    judged, chosen = [], False
    for item in checked:
        if item.row is None:
            judged.append(item)
            continue
        why = failures(item, default)
        name = item.name
        if not why and not chosen and item.name == "candidate":
            name, chosen = "recommended", True
        judged.append(replace(item, name=name, failed=why))
    return judged


def _margins(config: RunConfig, gains: PDGains) -> dict:
    """The closed loop's margins of `gains` on the run's nominal plant (worker.stability), the
    least over its trajectories: its tracking modes' damping at the plant's delay and at the
    largest delay any plant of the run has (the uncertainty range's top, where reviewers found
    tuned members unstable), and its delay margin in ticks. About an episode's cost each."""
    from gainfarm.worker.stability import margins  # start-up: MuJoCo, only for a check

    top = max(plant.delay for plant in (config.plant, *config.plants, *config.check_plants))
    found = [
        margins(config.episode_spec(gains, number), delay=top)
        for number in range(len(config.trajectories))
    ]
    least = min(found, key=lambda m: m.tracking)
    late = min(found, key=lambda m: m.tracking_at)
    return {
        "tracking": least.tracking,
        "tracking_hz": least.tracking_hz,
        "delay": top,
        "tracking_at_delay": late.tracking_at,
        "tracking_at_delay_hz": late.tracking_at_hz,
        "delay_margin": min(m.delay_margin for m in found),
    }


def _margin_failures(margins: dict | None, default: dict | None) -> list[str]:
    """Why `margins` fall short of the default gains' `default`: its tracking modes less damped
    than theirs at the largest delay the run's plants have (a controller a late packet makes
    ring where the factory gains do not is no improvement on a real arm)."""
    if not margins or not default:
        return []
    mine, theirs = margins["tracking_at_delay"], default["tracking_at_delay"]
    if mine < theirs - DAMPING_TOLERANCE:
        late = counted(margins["delay"], "tick")
        return [f"tracking damping {mine:.3f} {late} late < {theirs:.3f}"]
    return []


def _write(run: TuningRun, checked: Sequence[Checked], plants: int, asked: int, cost: dict) -> None:
    # "asked": the config's held-out plants; "plants": those the budget allowed (CHECK_SHARE).
    record = {
        "plants": plants,
        "asked": asked,
        "controllers": [asdict(item) for item in checked],
        "advice": next(
            (
                {"row": item.row, "kp": item.kp, "kd": item.kd}
                for item in checked
                if item.name == "recommended"
            ),
            {"row": None},
        ),
        "cost": cost,
    }
    front = run.directory / FRONT_JSON
    content = read_record(front)
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
        return read_record(path)
    except (OSError, ValueError):
        return None


def advice_of(record: dict | None) -> Advice | None:
    """The advice of a check record (check.json): the gains it recommends, or none (keep the
    default gains); None for no record, or one from before the check gave advice."""
    if not record or "advice" not in record:
        return None
    advice = record["advice"]
    if advice.get("row") is None:
        return Advice(None)
    return Advice(PDGains(kp=advice["kp"], kd=advice["kd"]))


def advice_in(directory) -> Advice | None:
    """The advice of the check of the run in `directory` (advice_of)."""
    return advice_of(read_check(directory))
