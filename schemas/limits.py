"""Safety limits: what a controller may not do on any of its episodes, whatever its objectives.

They are constraints of the optimisation, not objectives: a candidate that breaks one is
infeasible, ranked behind every feasible one (feasibility first) and never reported on a front,
exported or put in a dataset unless asked. This is their one place: each default says where it
comes from, or that it is an assumption; `analytic start|batch|experiment --limits FILE` (a JSON
object of some of these fields) overrides them, and the run keeps them in its config.json.

Each measure is a Scores field, computed from the episode's log by schemas.objectives.score (so
the worker and the referee agree on it), a share of a published limit where there is one. A
candidate's measure is its worst over all its episodes (every trajectory, every plant variant),
so a limit met holds on each. Its constraint value is g = measure / limit − 1, met when g ≤ 0
(pymoo's convention); a limit set to null is not checked (g = −1, as if the measure were 0).

One limit is a lower bound: `min_damping`, on the least damping ratio of the controller's closed
loop (Scores.damping, worker.stability; a candidate's is the least over its episodes, measured
after the others: MEASURED). It is not checked by default (None: a run's constraints are the four
above, as before it existed); set, it is one more constraint, g = min_damping − damping. A
damping ratio is already a dimensionless number in [−1, 1], and a share of a lower bound would
blow up at the natural bound 0 (stable at all).
"""

from collections.abc import Sequence
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from gainfarm.schemas.episode import Scores
from gainfarm.schemas.objectives import CHATTER_CUTOFF, SPEED_CAP

# The limited measures, in constraint order: Scores fields.
MEASURES = ("torque_step", "saturated_fraction", "speed", "chatter")
# A candidate with an episode that did not run is measured the worst any episode can be: never
# feasible, as its objectives are never preferred (schemas.objectives.NO_EPISODE).
NOT_MEASURED = (2.0, 1.0, SPEED_CAP, 2.0)
DAMPING = "damping"  # the lower-bounded measure: a Scores field
# What a candidate's measures hold: the upper-bounded ones, then its least damping ratio.
MEASURED = (*MEASURES, DAMPING)
# The least damping of a candidate with an episode that did not run, or that predates the margin:
# the least a damping ratio can be, so never feasible under a `min_damping`.
NOT_DAMPED = -1.0
UNITS = {
    "torque_step": "share of the joint's torque limit, per 2 ms tick",
    "saturated_fraction": "share of ticks with a joint at its torque limit",
    "speed": "share of the joint's data-sheet speed limit",
    "chatter": f"RMS above {CHATTER_CUTOFF:g} Hz, share of the joint's torque limit",
    DAMPING: "least damping ratio of the closed loop along the reference, at least",
}

Limit = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class Limits(BaseModel):
    """The largest value each safety measure may take on any episode of a candidate."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    torque_step: Limit | None = Field(
        0.1,
        # Assumption: KUKA publishes no torque rate. A tenth of the joint's limit in 2 ms (32
        # N·m on A1, 4 N·m on A7) is 11 times the default gains' largest step and 6 times that
        # of the smooth controllers measured (bench/limit_measures.py); the chattering ones step
        # by 0.44 to 2 (a real arm's safety stop would trip).
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
        1.5,
        # Source: KUKA's LBR iiwa 14 R820 data sheet (schemas.robot.SPEED_LIMITS), which the
        # measure is a share of. The 50 % over it is an assumption: a reference may use the full
        # rated speed (worker.reference), and smooth controllers overshoot a fast one (up to
        # 1.37 on a 3 s pyramid, bench/limit_measures.py); the chattering ones reach 3.6 to 6.7.
        description="largest measured joint speed, share of KUKA's data-sheet speed limit "
        "(source: the data sheet; the 50 % over it for tracking fast references an assumption)",
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

    min_damping: float | None = Field(
        None,
        ge=-1,
        le=1,
        allow_inf_nan=False,
        # No default: how much damping a controller needs is the user's call (0 asks for a
        # stable loop; the default gains keep 0.013 on the realistic plant, bench/damping.py).
        description="the least damping ratio of its closed loop each episode must keep: a lower "
        "bound (worker.stability; null: not checked)",
    )

    def values(self) -> tuple[float | None, ...]:
        """The upper limits, in MEASURES' order."""
        return tuple(getattr(self, name) for name in MEASURES)

    @property
    def names(self) -> tuple[str, ...]:
        """The constraints' names, in `constraints`' order: the damping's last, if bounded."""
        return MEASURES if self.min_damping is None else MEASURED

    @property
    def count(self) -> int:
        """How many constraint values `constraints` gives."""
        return len(self.names)

    def constraints(self, measured: Sequence[float]) -> tuple[float, ...]:
        """g per limit, met when ≤ 0: measure / limit − 1 for each of MEASURES, then
        min_damping − damping if it is bounded. `measured` is in MEASURED's order (a record from
        before the damping lacks it, and is judged on the others alone)."""
        upper = tuple(
            -1.0 if limit is None else float(value) / limit - 1.0
            for value, limit in zip(measured[: len(MEASURES)], self.values(), strict=True)
        )
        if self.min_damping is None:
            return upper
        damping = measured[len(MEASURES)] if len(measured) > len(MEASURES) else self.min_damping
        return (*upper, self.min_damping - float(damping))

    def violated(self, measured: Sequence[float]) -> tuple[str, ...]:
        """The names of the limits `measured` (MEASURED's order) break."""
        return tuple(
            name for name, g in zip(self.names, self.constraints(measured), strict=True) if g > 0
        )


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
