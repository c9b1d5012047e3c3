"""Safety limits: what a controller may not do on any of its episodes, whatever its objectives.

They are constraints of the optimisation, not objectives: a candidate that breaks one is
infeasible, ranked behind every feasible one (feasibility first) and never reported on a front,
exported or put in a dataset unless asked. This is their one place: each default says where it
comes from, or that it is an assumption; `analytic start|batch|experiment --limits FILE` (a JSON
object of some of these fields) overrides them, and the run keeps them in its config.json.

Each measure is a Scores field, computed from the episode's log by schemas.objectives.score (so
the worker and the referee agree on it), a share of a published limit where there is one, else
an angle (`lag`: the worst joint's RMS lag behind its reference, which f_acc, the flange's
position only, cannot see for the wrist). A candidate's measure is its worst over all its
episodes (every trajectory, every plant variant), so a limit met holds on each. Its constraint
value is g = measure / limit − 1, met when g ≤ 0 (pymoo's convention); a limit set to null is not
checked (g = −1, as if the measure were 0), and the lag's, added after the first four, is then no
constraint at all (OPTIONAL), as the damping's bound below. The speed is judged with a stated
tolerance over its limit, for a controller's overshoot of a reference at up to the rated speed:
g = speed / (limit · (1 + SPEED_TOLERANCE)) − 1.

One limit is a lower bound: `min_damping`, on the least damping ratio of the controller's closed
loop (Scores.damping, worker.stability; a candidate's is the least over its episodes, measured
after the others: MEASURED). It is one more constraint, g = min_damping − damping, after the
five above (null: not checked, and not a constraint). A damping ratio is already a dimensionless
number in [−1, 1], and a share of a lower bound would blow up at the natural bound 0.

The defaults are argued from measurements of the iiwa 14 (bench/limit_measures.py --variants 8),
and are shares of each arm's own limits, which its logs carry (EpisodeMetadata): each keeps the
default gains feasible on the 5 s spiral, fourier and pyramid paths, on the nominal plant and
on robust runs' plant variants (where the default gains run away on some variant, as on 4 of the
9 seeds measured, they break the torque step, chatter and speed limits, whatever these are).
A run's config.json from before a limit existed does not check it (RunConfig), so a resumed run
keeps its constraints; a record from before the lag reads it as 0.0 (`named`).
"""

from collections.abc import Mapping, Sequence
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from gainfarm.schemas.episode import Scores
from gainfarm.schemas.objectives import CHATTER_CUTOFF, LAG_CAP, SPEED_CAP

# The limited measures, in constraint order: Scores fields.
MEASURES = ("torque_step", "saturated_fraction", "speed", "chatter", "lag")
# A candidate with an episode that did not run is measured the worst any episode can be: never
# feasible, as its objectives are never preferred (schemas.objectives.NO_EPISODE).
NOT_MEASURED = (2.0, 1.0, SPEED_CAP, 2.0, LAG_CAP)
# The measures a record from before the lag holds, in order (then its damping, if measured).
BEFORE_LAG = MEASURES[:-1]
DAMPING = "damping"  # the lower-bounded measure: a Scores field
# What a candidate's measures hold: the upper-bounded ones, then its least damping ratio.
MEASURED = (*MEASURES, DAMPING)
# The share over its limit a measured joint speed may reach (assumption, from measurements): a
# reference may use the full rated speed (worker.reference), and a tracking controller overshoots
# it; the default gains by 2 to 10 % on the realistic plant (the 5 s paths 2 to 5 %, a 3 s
# pyramid, its reference at 0.91, 10 %; bench/limit_measures.py --variants 8). So a speed is
# judged against limit × (1 + SPEED_TOLERANCE), as a real arm's speed monitor is set a little
# above the speed its planner may command.
SPEED_TOLERANCE = 0.1
# The limits added since the first four: each a constraint only when set, so a run from before
# it (its config.json's limits read as null: analytic.tuning.config) resumes with the same count.
OPTIONAL = {"lag": "lag", DAMPING: "min_damping"}
# The least damping of a candidate with an episode that did not run, or that predates the margin:
# the least a damping ratio can be, so never feasible under a `min_damping`.
NOT_DAMPED = -1.0
UNITS = {
    "torque_step": "share of the joint's torque limit, per 2 ms tick",
    "saturated_fraction": "share of ticks with a joint at its torque limit",
    "speed": f"share of the joint's data-sheet speed limit (a {SPEED_TOLERANCE:.0%} tolerance "
    "over it)",
    "chatter": f"RMS above {CHATTER_CUTOFF:g} Hz, share of the joint's torque limit",
    "lag": "largest RMS of a joint's angle less its reference's, rad",
    DAMPING: "least damping ratio of the closed loop along the reference, at least",
}

Limit = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class Limits(BaseModel):
    """The largest value each safety measure may take on any episode of a candidate."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    torque_step: Limit | None = Field(
        0.1,
        # Assumption: KUKA publishes no torque rate; the same share serves every arm. A tenth of
        # the joint's limit in 2 ms (on the iiwa 14: 32 N·m on A1, 4 on A7) is 11 times the
        # default gains' largest step and 6 times that of the smooth controllers measured
        # (bench/limit_measures.py); the chattering ones step by 0.44 to 2 (a real arm's safety
        # stop would trip).
        description="largest torque change in one tick, share of the joint's torque limit "
        "(assumption: KUKA publishes no torque rate)",
    )
    saturated_fraction: Limit | None = Field(
        0.01,
        # Assumption: a clipped command is a controller asking for what the motor cannot give;
        # 1 % of the ticks (50 ms of a 5 s episode) tolerates a brief touch of the limit.
        description="share of ticks with a joint at its torque limit (assumption)",
    )
    speed: Limit | None = Field(
        1.0,
        # Source: the robot's data sheet (its Robot.limits.speed, which every log carries: the iiwa
        # 14's is KUKA's LBR iiwa 14 R820 data sheet), which the measure is a share of, checked with
        # SPEED_TOLERANCE (10 %) over it: a reference may use the full rated speed
        # (worker.reference), and a real arm's speed monitor is set a little above what its planner
        # commands. The default gains reach 0.52 (5 s spiral), 0.57 (5 s pyramid), 0.89 (fourier,
        # its reference at 0.85) and 1.005 (a 3 s pyramid, its reference at 0.91) on the realistic
        # plant; at most 0.91 on the 5 s paths on robust runs' variants. A reference at the full
        # rated speed (a path at its shortest duration: 0.98) they overshoot to 1.05 (spiral) and
        # 1.11 (pyramid): such a path wants planning a little slower. Chattering controllers reach
        # 2.5 to 11 (bench/limit_measures.py --variants 8).
        description="largest measured joint speed, share of the robot's data-sheet speed limit "
        "(source: the data sheet; checked with a 10 % tolerance for a controller's overshoot of "
        "a reference at up to the rated speed, an assumption)",
    )
    chatter: Limit | None = Field(
        0.02,
        # Assumption: the RMS of a joint's command above CHATTER_CUTOFF (the arm's lowest
        # elastic mode, schemas.objectives) at 2 % of its torque limit (6.4 N·m on A1, 0.8 N·m
        # on A7). The default gains put at most 0.05 % there, the smooth controllers measured
        # at most 0.8 %, the chattering ones 50 % to 99 % (bench/limit_measures.py).
        description="RMS of the command above 10 Hz, share of the joint's torque limit "
        "(assumption; the cut-off is the arm's lowest elastic mode)",
    )
    lag: Limit | None = Field(
        0.06,
        # Assumption, from measurements: the worst joint's RMS lag behind its reference, an
        # angle. 0.06 rad (3.4°) moves a tool 10 cm from the flange by 6 mm RMS about A7, the
        # joint the flange's position (f_acc) cannot see. The default gains lag at most 7.0 mrad
        # on the realistic plant (A7, spiral 6.0, fourier 7.0, pyramid 6.1) and at most 51 on
        # robust runs' variants (A7, the pyramid; seeds 0-8 x 8 variants; 54 among 16 variants
        # of seed 1), which the limit must keep feasible. A7 at a hundredth of its gains lags 230
        # to 460 mrad, gains a third of the defaults' up to 207 (bench/limit_measures.py
        # --variants 8).
        description="largest RMS of a joint's angle less its reference's, rad (assumption: "
        "6 mm RMS at a tool 10 cm from the flange; the default gains' worst measured 54 mrad)",
    )

    min_damping: float | None = Field(
        -0.1,
        ge=-1,
        le=1,
        allow_inf_nan=False,
        # From measurements (bench/limit_measures.py --variants 8, bench/damping.py): a run
        # judges the least over all its episodes, every plant variant's, and the default gains,
        # +0.013 on the realistic plant, keep +0.014 to -0.086 on robust runs' variants (seeds
        # 0-8, 8 each) while their episodes stay smooth (chatter at most 0.001; the margin
        # freezes the arm at a pose, where the Coulomb friction that damps it along the motion
        # is flat). So no bound at or above zero leaves them feasible: -0.1 does, and refuses
        # loops far from damped, like the search space's top (-0.102 to -0.104 on the realistic
        # plant, -0.15 to -0.17 on variants). Controllers that run away less unstably (-0.03 to
        # -0.07) are the chatter, speed and torque step limits' to catch.
        description="the least damping ratio of its closed loop each episode must keep: a lower "
        "bound (worker.stability; null: not checked; -0.1 keeps the default gains on every "
        "robust run's variants measured)",
    )

    def values(self) -> tuple[float | None, ...]:
        """The upper limits, in MEASURES' order."""
        return tuple(getattr(self, name) for name in MEASURES)

    def allowed(self, name: str) -> float | None:
        """The most measure `name` (one of MEASURES) may be: its limit, the speed's with its
        SPEED_TOLERANCE; None if it is not checked."""
        limit = getattr(self, name)
        if limit is None or name != "speed":
            return limit
        return limit * (1.0 + SPEED_TOLERANCE)

    @property
    def names(self) -> tuple[str, ...]:
        """The constraints' names, in `constraints`' order: the first four measures', the lag's
        if it is set, then the damping's if it is bounded (OPTIONAL: a run from before them
        resumes with the constraints it had)."""
        return tuple(
            name
            for name in MEASURED
            if name not in OPTIONAL or getattr(self, OPTIONAL[name]) is not None
        )

    @property
    def count(self) -> int:
        """How many constraint values `constraints` gives."""
        return len(self.names)

    def constraints(self, measured: Sequence[float]) -> tuple[float, ...]:
        """g per limit of `names`, met when ≤ 0: measure / limit − 1 for each upper one (−1 if
        it is null), then min_damping − damping if it is bounded. `measured` is in MEASURED's
        order (a record from before the damping lacks it, and is judged on the others alone)."""
        values = dict(zip(MEASURED, (float(value) for value in measured), strict=False))
        if len(values) < len(MEASURES):
            raise ValueError(f"{len(values)} measures, not {len(MEASURES)} or {len(MEASURED)}")
        upper = tuple(
            -1.0 if self.allowed(name) is None else values[name] / self.allowed(name) - 1.0
            for name in self.names
            if name != DAMPING
        )
        if self.min_damping is None:
            return upper
        return (*upper, self.min_damping - values.get(DAMPING, self.min_damping))

    def violated(self, measured: Sequence[float]) -> tuple[str, ...]:
        """The names of the limits `measured` (MEASURED's order) break."""
        return tuple(
            name for name, g in zip(self.names, self.constraints(measured), strict=True) if g > 0
        )


def named(values: Mapping[str, float | str]) -> tuple[float, ...]:
    """A candidate's measures as a record names them (front.json, evaluated.csv), in MEASURED's
    order: none from a run before the limits; the lag 0.0 in one from before it (as Scores reads
    it: never a violation); without the damping in one from before that."""
    if not values:
        return ()
    upper = tuple(float(values.get(name, 0.0)) for name in MEASURES)
    return upper if DAMPING not in values else (*upper, float(values[DAMPING]))


def before_lag(measured: Sequence[float]) -> tuple[float, ...]:
    """Measures kept in BEFORE_LAG's order (then the damping, if measured: a checkpoint's from
    before the lag), in MEASURED's: the lag 0.0 inserted, as `named` reads it."""
    values = tuple(float(value) for value in measured)
    return (*values[: len(BEFORE_LAG)], 0.0, *values[len(BEFORE_LAG) :])


def measures(scores: Sequence[Scores | None]) -> tuple[float, ...]:
    """A candidate's measures over its episodes, in MEASURED's order: the worst of each, the
    highest of MEASURES and the least damping (NOT_MEASURED and NOT_DAMPED if it has none, or one
    did not run; NOT_DAMPED if one was not measured for its damping)."""
    if not scores or any(score is None for score in scores):
        return (*NOT_MEASURED, NOT_DAMPED)
    ran = [score for score in scores if score is not None]
    dampings = [score.damping for score in ran]
    least = NOT_DAMPED if None in dampings else min(float(d) for d in dampings if d is not None)
    return (*(max(float(getattr(score, name)) for score in ran) for name in MEASURES), least)


def tally(limits: Limits, measured: Sequence[Sequence[float]]) -> tuple[int, dict[str, int]]:
    """How many candidates of `measured` break a limit, and how many break each (one may break
    several), in `limits.names`' order."""
    broken = [limits.violated(values) for values in measured]
    return sum(1 for names in broken if names), {
        name: sum(1 for names in broken if name in names) for name in limits.names
    }


def feasible(constraints: Sequence[float]) -> bool:
    """Whether constraint values (Limits.constraints) meet every limit."""
    return all(g <= 0 for g in constraints)
