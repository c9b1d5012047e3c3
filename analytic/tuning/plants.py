"""Plant variants: what robust tuning scores every candidate on besides the nominal plant.

The ranges are data: the robot's own (`Robot.uncertainty`; the iiwa 14's is
models/uncertainty.toml, each with its source or labelled an assumption), or a file of the same
form (`--uncertainty FILE`). A per-joint range names one pair per joint of the robot it is drawn
for (checked when drawn: a table alone names no robot). `variants` draws K plants from them
once, from the run's seed, so every candidate meets the same K (common random numbers: a
difference between two candidates is theirs, not the draw's). Pure: numbers in, PlantSpecs out.
"""

import tomllib
from collections.abc import Callable, Sequence
from importlib.resources import files
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from gainfarm.models import min_substeps, resolve, robot_of
from gainfarm.schemas.documents import QUOTED, BadDocument, load_toml
from gainfarm.schemas.robot import DEFAULT_ROBOT, MAX_JOINTS, PlantSpec
from gainfarm.schemas.wire import describe

# The iiwa 14's ranges (its Robot.uncertainty): what a table of the shipped form looks like.
UNCERTAINTY = files("gainfarm.models").joinpath("uncertainty.toml")
# The fields a range may move, and whether PlantSpec holds one value per joint there.
# `load.mass_scale` is the error of the load data the robot is told (schemas.robot.LoadData).
FIELDS = {
    "mass_scale": True,
    "payload": False,
    "load.mass_scale": False,
    "rotor_inertia": True,
    "stiffness": True,
    "spring_damping": True,
    "friction.coulomb": True,
    "friction.viscous": True,
    "delay": False,
    "sensors.noise": False,
    "sensors.torque_noise": False,
}


Bound = float | tuple[float, ...]


class Range(BaseModel):
    """One group of the plant's numbers and how far it may be off: each variant draws a factor
    on the nominal value (or, `absolute`, the value itself) between `low` and `high`, one pair
    for every joint or, per joint, a pair for each joint of the robot (a calibrated twin knows
    some joints better)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    field: Literal[tuple(FIELDS)]  # type: ignore[valid-type]
    per_joint: bool = False
    absolute: bool = False
    draw: Literal["log", "uniform", "integer"]
    low: Bound
    high: Bound
    why: str = Field(min_length=1, description="its source, or that it is an assumption")

    @model_validator(mode="after")
    def _sensible(self) -> "Range":
        if self.per_joint and not FIELDS[self.field]:
            raise ValueError(f"{self.field} is one number, not one per joint")
        for name in ("low", "high"):
            bound = getattr(self, name)
            if isinstance(bound, tuple) and not (self.per_joint and 1 <= len(bound) <= MAX_JOINTS):
                raise ValueError(f"{name}: one number, or one per joint with per_joint = true")
            values = np.atleast_1d(bound)
            if not (np.isfinite(values).all() and (values >= 0).all()):
                raise ValueError(f"{name}: finite and non-negative numbers expected")
        low, high = np.atleast_1d(self.low), np.atleast_1d(self.high)
        if len(low) > 1 and len(high) > 1 and len(low) != len(high):
            raise ValueError(f"low has {len(low)} numbers and high {len(high)}: one per joint")
        if (high < low).any():
            raise ValueError(f"high {_show(self.high)} is below low {_show(self.low)}")
        if self.draw == "log" and (low <= 0).any():
            raise ValueError("a log draw needs low > 0")
        return self

    def joints(self) -> int | None:
        """How many joints its per-joint bounds name (None: one pair for every joint)."""
        sizes = {len(b) for b in (self.low, self.high) if isinstance(b, tuple)}
        return sizes.pop() if sizes else None


def _show(bound: Bound) -> str:
    return f"{bound:g}" if isinstance(bound, float | int) else ", ".join(f"{v:g}" for v in bound)


class BadUncertainty(ValueError):
    """An uncertainty file that is not one: the message says where and what, in one line."""


def ranges(text: str | None = None, robot: str = DEFAULT_ROBOT) -> dict[str, Range]:
    """The ranges in `text` (TOML), or the robot's own (`Robot.uncertainty`); BadUncertainty in
    one line."""
    try:
        table = load_toml(robot_of(robot).uncertainty.read_text() if text is None else text)
    except tomllib.TOMLDecodeError as error:
        raise BadUncertainty(f"not TOML: {error}") from None
    except BadDocument as error:
        raise BadUncertainty(str(error)) from None
    return ranges_of(table)


def ranges_of(table: dict) -> dict[str, Range]:
    """The ranges in a parsed table (a plant file's uncertainty); BadUncertainty in one line."""
    found = {}
    for name, entry in table.items():
        if not isinstance(entry, dict):
            raise BadUncertainty(
                f"{name[:QUOTED]}: a table of field, draw, low, high and why expected"
            )
        try:
            found[name] = Range.model_validate(entry)
        except ValidationError as error:
            raise BadUncertainty(f"{name[:QUOTED]}: {describe(error)}") from None
    return found


TUNING, HELD_OUT = 0, 1  # the streams of a seed: the variants tuned on, those checked on


def variants(
    nominal: PlantSpec,
    count: int,
    seed: int,
    uncertainty: dict[str, Range] | None = None,
    stream: int = TUNING,
) -> tuple[PlantSpec, ...]:
    """`count` plants drawn around `nominal` from `uncertainty` (default: its robot's ranges),
    deterministic in `seed` and `stream` (TUNING, HELD_OUT: never the same plants). Each has its
    own sensor noise seed and the physics steps its springs need (at least the nominal's).
    BadUncertainty if a per-joint range is for another joint count than the robot's."""
    table = _for(nominal, uncertainty)
    joints = len(robot_of(nominal).joint_names)
    rng = np.random.default_rng([seed, 0x706C616E7473, stream])  # "plants", its own stream
    nominal = resolve(nominal)  # the numbers a draw scales, written out
    drawn = []
    for _ in range(count):
        values = nominal.model_dump()
        for item in table.values():
            _apply(values, item, rng, joints)
        values["sensors"]["seed"] = int(rng.integers(2**63))
        drawn.append(stepped(PlantSpec.model_validate(values)))
    return tuple(drawn)


def _for(nominal: PlantSpec, uncertainty: dict[str, Range] | None) -> dict[str, Range]:
    """`uncertainty`, or the ranges of `nominal`'s robot, each checked to fit its joints."""
    table = ranges(robot=nominal.robot) if uncertainty is None else uncertainty
    robot = robot_of(nominal)
    joints = len(robot.joint_names)
    for name, item in table.items():
        if item.joints() not in (None, joints):
            raise BadUncertainty(
                f"{name[:QUOTED]}: {item.joints()} numbers per bound for {robot.name}'s "
                f"{joints} joints ({', '.join(robot.joint_names)})"
            )
    return table


def _apply(values: dict, item: Range, rng: np.random.Generator, joints: int) -> None:
    """Move `item`'s field of the dumped spec `values` (of a robot of `joints` joints) by one
    draw."""
    if item.field.startswith("load.") and values.get("load") is None:
        # The error of a told load: a plant told of none draws nothing for it, so its variants
        # are, draw for draw, those drawn before a load could be told.
        return
    size = joints if item.per_joint else 1
    low, high = np.asarray(item.low, dtype=float), np.asarray(item.high, dtype=float)
    if item.draw == "integer":
        draw = rng.integers(low.astype(int), high.astype(int) + 1, size=size).astype(float)
    elif item.draw == "log":
        draw = np.exp(rng.uniform(np.log(low), np.log(high), size=size))
    else:
        draw = rng.uniform(low, high, size=size)
    _move(values, item, draw)


def _move(values: dict, item: Range, draw: np.ndarray) -> None:
    """Set `item`'s field of the dumped spec `values` to `draw` times its nominal value (or, if
    `absolute`, to `draw`)."""
    *parents, name = item.field.split(".")
    holder = values
    for parent in parents:
        holder = holder.get(parent) or {}
    if name not in holder:  # a field the nominal plant has not (no friction): nothing to move
        return
    current = holder[name]
    if isinstance(current, Sequence) and not isinstance(current, str):
        base = np.asarray(current, dtype=float)
        with np.errstate(over="ignore"):  # an overflow is inf, which PlantSpec refuses
            moved = draw * (1.0 if item.absolute else base)
        holder[name] = tuple(float(v) for v in np.broadcast_to(moved, base.shape))
    else:
        moved = float(draw[0] if item.absolute else draw[0] * current)
        holder[name] = round(moved) if item.draw == "integer" else moved


End = Literal["low", "high"]


def corner(
    nominal: PlantSpec,
    ends: dict[str, End],
    uncertainty: dict[str, Range] | None = None,
    share: float = 1.0,
) -> PlantSpec:
    """`nominal` with each range `ends` names (a key of `uncertainty`, default its robot's
    ranges) at its low or high end, every joint alike, or `share` of the way there from the
    nominal plant (a log range's factor on its logarithm); the others nominal. KeyError for a
    range the table has not."""
    table = _for(nominal, uncertainty)
    joints = len(robot_of(nominal).joint_names)
    values = resolve(nominal).model_dump()
    for name, end in ends.items():
        item = table[name]
        size = joints if item.per_joint else 1
        bound = np.asarray(getattr(item, end), dtype=float)
        bound = np.broadcast_to(bound, (size,)) if bound.ndim == 0 else bound
        _move(values, item, _partway(values, item, bound, share))
    plant = PlantSpec.model_validate(values)
    return stepped(plant)


def _partway(values: dict, item: Range, bound: np.ndarray, share: float) -> np.ndarray:
    """The draw that moves `item`'s field of the dumped spec `values` `share` of the way from
    its nominal value to `bound` (1: `bound` itself)."""
    if share == 1.0:
        return bound
    if not item.absolute:  # a factor on the nominal value: 1 is the nominal
        return bound**share if item.draw == "log" else 1.0 + share * (bound - 1.0)
    *parents, name = item.field.split(".")
    holder = values
    for parent in parents:
        holder = holder.get(parent) or {}
    current = np.asarray(holder.get(name, 0.0), dtype=float)
    moved = current + share * (bound - current)
    return np.round(moved) if item.draw == "integer" else moved


def stepped(plant: PlantSpec) -> PlantSpec:
    """`plant` with the physics steps its springs need (at least its own), validated: a spring
    too stiff for PlantSpec's most steps per tick is refused (ValidationError, naming
    substeps), never simulated in millions of steps."""
    needed = min_substeps(plant)
    if needed <= plant.substeps:
        return plant
    return PlantSpec.model_validate({**plant.model_dump(), "substeps": needed})


# The designed plants robust tuning scores every candidate on first (`design`): two opposite
# corners of the ranges, where a sensitivity screen (bench/corners.py, docs/tuning.md) of the
# default gains and a nominal run's front found controllers break:
# - heavy: the robot's gravity model short of the most (the largest unknown load, a told load
#   at its heaviest, every link heavier) with the most friction, where every controller's error
#   grows most (7-8x on the spiral), and the command late by the range's top on the softest
#   joints: the lowest elastic modes, nearest the tracking loop's;
# - light: gravity over-compensated with the least friction to damp the arm, the command as
#   late, on the stiffest joints with the lightest rotors and the least damped springs: the
#   highest, least damped elastic modes.
# On each, most of a nominal front is unstable (least damping ratio below 0) where the default
# gains keep +0.003 and +0.012. The heaviest rotors (10x) are left out of the heavy corner: with
# them the default gains break the speed and lag limits on any path faster than the 5 s spiral
# (a 4 s Fourier path: 1.19 times the rated speed, 86 mrad), and a run on such a path would have
# no feasible candidate. The heavy end with the light one's joints is beyond what the default
# gains hold (-0.14). Sensor noise and spring damping alone move no controller's error.
CORNERS: dict[str, dict[str, End]] = {
    "heavy": {
        "payload": "high",
        "load_mass": "high",
        "mass_scale": "high",
        "coulomb": "high",
        "viscous": "high",
        "delay": "high",
        "stiffness": "low",
    },
    "light": {
        "payload": "low",
        "load_mass": "low",
        "mass_scale": "low",
        "coulomb": "low",
        "viscous": "low",
        "delay": "high",
        "rotor_inertia": "low",
        "stiffness": "high",
        "spring_damping": "low",
    },
}


def design(
    nominal: PlantSpec,
    count: int,
    seed: int,
    uncertainty: dict[str, Range] | None = None,
    shares: Sequence[float] = (),
) -> tuple[PlantSpec, ...]:
    """The `count` plants robust tuning scores every candidate on besides `nominal`: the
    CORNERS first (as many as `count` allows; a range `uncertainty` lacks stays nominal there;
    each `shares` of the way from the nominal plant, 1 if not given: `held_design`), then random
    draws (`variants`, TUNING stream). Each has its own sensor noise seed, drawn from `seed`."""
    table = _for(nominal, uncertainty)
    rng = np.random.default_rng([seed, 0x636F726E657273])  # "corners": a stream of its own
    designed = []
    for index, ends in enumerate(list(CORNERS.values())[:count]):
        share = shares[index] if index < len(shares) else 1.0
        chosen = {name: end for name, end in ends.items() if name in table}
        plant = corner(nominal, chosen, table, share)
        sensors = plant.sensors.model_copy(update={"seed": int(rng.integers(2**63))})
        designed.append(plant.model_copy(update={"sensors": sensors}))
    return (*designed, *variants(nominal, count - len(designed), seed, table))


# How often `held_design` halves a corner's way from the nominal plant: at most to an eighth.
HALVINGS = 3


def held_design(
    nominal: PlantSpec,
    count: int,
    seed: int,
    holds: Callable[[PlantSpec], bool],
    uncertainty: dict[str, Range] | None = None,
) -> tuple[tuple[PlantSpec, ...], tuple[float, ...]]:
    """`design`'s plants with each corner where the robot's default gains hold (`holds`: they
    keep to the run's limits there), and each corner's share of the way to the ranges' ends.

    The corners are the most adverse plants the factory controller still keeps to the limits on
    (the iiwa 14's are, at the ranges' ends: CORNERS); on an arm whose ranges reach further (the
    UR5e's rotors, 0.25-4x), a corner at their ends can be one the default gains break, and then
    no candidate can be judged against them. Such a corner is moved half the way back to the
    nominal plant, up to HALVINGS times; one the default gains break even then is kept there (the
    check says what they break)."""
    shares = []
    for index in range(min(count, len(CORNERS))):
        share = 1.0
        for _ in range(HALVINGS):
            plant = design(nominal, index + 1, seed, uncertainty, (*shares, share))[index]
            if holds(plant):
                break
            share /= 2
        shares.append(share)
    return design(nominal, count, seed, uncertainty, shares), tuple(shares)
