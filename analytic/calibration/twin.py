"""The twin as a plant file: the fitted plant, its uncertainty as ranges, and its provenance.

The ranges are in models/uncertainty.toml's form, around the twin's own numbers, so that robust
tuning on the twin (`analytic start --plant TWIN --plants K`) draws its variants from what the
calibration could not pin down rather than from the project's assumptions: a number the logs
told spans SPREAD bootstrap standard deviations each way (at least FLOOR), per joint; one they
could not tell keeps the shipped range and its source.

A twin is of one arm: its plant names the robot (and its calibration record says it again), and
it stands for no other (`for_robot`: refused in one line).
"""

import hashlib
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from gainfarm.analytic.calibration.identify import FLOOR, SPREAD, Estimate, Fit
from gainfarm.analytic.tuning.plants import Range, ranges
from gainfarm.models import robot_of
from gainfarm.schemas.plant_file import PlantFile
from gainfarm.schemas.robot import DEFAULT_ROBOT, PlantSpec

# The ranges a calibration replaces where it tells the numbers: each is the Fit's estimate of
# the same name.
CALIBRATED = ("rotor_inertia", "stiffness", "spring_damping", "coulomb", "viscous")


class OtherArm(ValueError):
    """A twin (a plant file) of one arm given for another: the message is one line."""


def for_robot(plant: PlantSpec, robot: str, option: str = "--plant") -> PlantSpec:
    """`plant` (a twin's, a plant file's) if it is of `robot`; else OtherArm, one line naming
    `option`: a twin's numbers are one arm's joints, links and motors, no other's."""
    if plant.robot != robot:
        raise OtherArm(
            f"{option}: a twin of {plant.robot} cannot stand for {robot} (calibrate {robot}'s "
            f"own logs: analytic calibrate --robot {robot})"
        )
    return plant


def shipped_ranges(robot: str) -> dict[str, Range]:
    """The uncertainty ranges `robot` ships (the iiwa 14's: models/uncertainty.toml)."""
    return ranges() if robot == DEFAULT_ROBOT else ranges(robot_of(robot).uncertainty.read_text())


def twin_file(
    fit: Fit, nominal: PlantSpec, logs: Sequence[Path], prior: dict[str, Range] | None = None
) -> PlantFile:
    """The plant file of `fit` on `nominal`, naming the logs it came from; where the logs tell
    nothing, the ranges are `prior`'s (a twin's own, calibrated again), else the ones `nominal`'s
    robot ships."""
    uncertainty: dict[str, dict[str, Any]] = {}
    arm = robot_of(nominal)
    joints = len(arm.joint_names)
    for name, entry in (prior or shipped_ranges(nominal.robot)).items():
        estimate = getattr(fit, name) if name in CALIBRATED else None
        if estimate is None or not estimate.told.any():
            if name == "payload":  # the shipped range is absolute: around no payload
                uncertainty[name] = _payload_range(fit.payload, arm.rated_payload)
            elif name == "delay":
                uncertainty[name] = _delay_range(fit)
            else:
                uncertainty[name] = entry.model_dump(mode="json")
            continue
        uncertainty[name] = _calibrated_range(entry.model_dump(mode="json"), estimate, joints)
    calibration = {
        "robot": nominal.robot,
        "logs": [{"name": Path(log).name, "sha256": _digest(log)} for log in logs],
        "episodes": fit.episodes,
        "ticks": fit.ticks,
        "delay": {"ticks": fit.delay, "support": fit.delay_support},
        "smoothing": {
            "fit": fit.smoothing.value,
            "spread": fit.smoothing.spread,
            "told": fit.smoothing.told,
        },
        **{name: _summary(getattr(fit, name)) for name in _ESTIMATES},
        "notes": list(fit.notes),
    }
    return PlantFile(plant=fit.plant(nominal), uncertainty=uncertainty, calibration=calibration)


_ESTIMATES = (
    "rotor_inertia",
    "viscous",
    "coulomb",
    "stiffness",
    "spring_damping",
    "mass_scale",
    "payload",
)


def write_text(plant_file: PlantFile) -> str:
    """The plant file as TOML, read back by schemas.plant_file.read_plant_file. A per-joint
    field the plant leaves None (the robot's own numbers) is left out: TOML has no None, and a
    field left out reads back None (a twin's are all written: the fit's or the nominal's)."""
    table = plant_file.model_dump(mode="json")
    plant = table["plant"]
    for field in _PER_JOINT:
        if plant.get(field, 0) is None:
            del plant[field]
    friction = plant.get("friction")
    if isinstance(friction, dict):  # None, no friction at all, is not the robot's own: kept
        table["plant"]["friction"] = {k: v for k, v in friction.items() if v is not None}
    return tomli_w.dumps(table)


# A plant's fields that None leaves to its robot (schemas.robot.PlantSpec).
_PER_JOINT = ("stiffness", "spring_damping", "rotor_inertia", "mass_scale")


def _calibrated_range(shipped: dict[str, Any], estimate: Estimate, joints: int) -> dict[str, Any]:
    """Per joint, SPREAD bootstrap deviations each way (at least FLOOR) where told, the shipped
    factors where not."""
    relative = estimate.spread / np.maximum(np.abs(estimate.value), 1e-12)
    half = np.maximum(SPREAD * relative, math.log1p(FLOOR))
    low = np.where(estimate.told, np.exp(-half), _per_joint(shipped["low"], joints))
    high = np.where(estimate.told, np.exp(half), _per_joint(shipped["high"], joints))
    return {
        "field": shipped["field"],
        "per_joint": True,
        "draw": "log",
        "low": [round(float(v), 6) for v in low],
        "high": [round(float(v), 6) for v in high],
        "why": f"calibrated: {SPREAD:g} bootstrap standard deviations each way, at least "
        f"{FLOOR:.0%}, where the logs told it; elsewhere the shipped range ({shipped['why']})",
    }


def _payload_range(payload: Estimate, rated: float) -> dict[str, Any]:
    """The fitted payload's range, absolute: the file keeps the payload untold, as on the arm the
    logs came from (validate replays them); a run on the file tells it (PlantFile.told), this
    range then the told load's error."""
    value, spread = float(payload.value[0]), float(payload.spread[0])
    half = max(SPREAD * spread, 0.5)
    return {
        "field": "payload",
        "absolute": True,
        "draw": "uniform",
        "low": round(max(value - half, 0.0), 6),
        "high": round(min(value + half, rated), 6),
        "why": f"calibrated: the fitted payload, {SPREAD:g} bootstrap standard deviations or "
        "0.5 kg each way (it trades against the last links' masses)",
    }


def _delay_range(fit: Fit) -> dict[str, Any]:
    certain = fit.delay_support >= 0.95
    low, high = (fit.delay, fit.delay) if certain else (max(fit.delay - 1, 0), fit.delay + 1)
    return {
        "field": "delay",
        "absolute": True,
        "draw": "integer",
        "low": low,
        "high": high,
        "why": f"calibrated: the delay that fits best in {fit.delay_support:.0%} of bootstrap "
        "resamples" + ("" if certain else "; one tick either way"),
    }


def _per_joint(bound: float | Sequence[float], joints: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(bound, dtype=float), (joints,))


def _summary(estimate: Estimate) -> dict[str, Any]:
    return {
        "fit": [float(v) for v in estimate.value],
        "spread": [float(v) for v in estimate.spread],
        "told": [bool(v) for v in estimate.told],
        "explained": [float(v) for v in estimate.explained],
        "why": estimate.why,
    }


def _digest(path: Path) -> str:
    """The file's SHA-256; a bag directory's, of its files' names and bytes in name order."""
    path = Path(path)
    if path.is_file():
        return hashlib.sha256(path.read_bytes()).hexdigest()
    digest = hashlib.sha256()
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        digest.update(str(file.relative_to(path)).encode() + b"\0" + file.read_bytes())
    return digest.hexdigest()
