"""A plant as a file: a calibrated twin of a real arm, or any plant a user writes down.

`analytic calibrate` writes one (TOML): the simulated plant it fitted to an arm's logs, how sure
it is of each number (its uncertainty, in the form of models/uncertainty.toml: robust tuning
draws its variants from it) and where the numbers came from. `--plant FILE` runs on it, on
`worker episode` as on the analytic commands; jobs carry the plant itself (a PlantSpec is every
number the simulation needs), so a worker needs no copy of the file. It lives in the contract
because the worker reads it and never imports the analytic layer; the uncertainty table is
checked by the analytic layer, which draws from it.
"""

import tomllib
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from gainfarm.schemas.documents import BadDocument, load_toml
from gainfarm.schemas.robot import RATED_PAYLOAD, LoadData, PlantSpec
from gainfarm.schemas.wire import describe

FORMAT = "gainfarm-plant/1"
MAX_FILE_BYTES = 1 << 20  # a plant is a few kB; anything larger is not one


class PlantFile(BaseModel):
    """What a plant file holds."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    format: str = Field(FORMAT, pattern=r"^gainfarm-plant/1$")
    plant: PlantSpec
    uncertainty: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="how far each calibrated number may be off: ranges in the form of "
        "models/uncertainty.toml, around this plant (empty: the shipped ranges)",
    )
    calibration: dict[str, Any] = Field(
        default_factory=dict, description="where the numbers came from: logs, fit, residuals"
    )

    def told(self) -> "PlantFile":
        """The file as a run uses it: a calibrated payload (the mass the logs found at the
        flange, untold on the arm they came from, which `analytic validate` replays) becomes
        part of the load the robot is told, and its range the error of that load data (a factor
        on the told mass) with nothing left untold. Unchanged unless the calibration found one:
        a fitted payload whose range excludes zero (its low above 0), the told total within the
        rated payload."""
        fitted = self._fitted_payload()
        if fitted is None:
            return self
        load, payload = self.plant.load, self.plant.payload
        held = 0.0 if load is None else load.mass * load.mass_scale  # a load told already
        total = held + payload
        if total > RATED_PAYLOAD:
            return self
        # Gravity reads only a body's mass and centre: the two as one, at their common centre.
        x, y, z = (0.0, 0.0, 0.0) if load is None else (held * v / total for v in load.com)
        told = LoadData(mass=total, com=(x, y, z))
        plant = self.plant.model_copy(update={"payload": 0.0, "load": told})
        uncertainty = dict(self.uncertainty)
        uncertainty["load_mass"] = {
            "field": "load.mass_scale",
            "draw": "uniform",
            "low": round((held + fitted[0]) / total, 6),
            "high": round((held + fitted[1]) / total, 6),
            "why": f"calibrated: the fitted payload's range ({fitted[2]}), as a factor on the "
            "told load it became part of",
        }
        uncertainty["payload"] = {
            "field": "payload",
            "absolute": True,
            "draw": "uniform",
            "low": 0.0,
            "high": 0.0,
            "why": "calibrated: the logs weighed what the arm holds, and the robot is told it",
        }
        return self.model_copy(update={"plant": plant, "uncertainty": uncertainty})

    def _fitted_payload(self) -> tuple[float, float, str] | None:
        """(low, high, why) of the payload a calibration found, or None if it found none."""
        fitted = self.uncertainty.get("payload")
        if "payload" not in self.calibration or not isinstance(fitted, dict):
            return None
        low, high = fitted.get("low"), fitted.get("high")
        if not (fitted.get("absolute") is True and fitted.get("field") == "payload"):
            return None
        if not (isinstance(low, int | float) and isinstance(high, int | float)):
            return None
        if not 0 < low <= self.plant.payload <= high:  # a range that excludes no payload
            return None
        return float(low), float(high), str(fitted.get("why", ""))


class BadPlantFile(ValueError):
    """Not a plant file, or not one this farm can simulate: the message says why, in one line."""


def read_plant_file(raw: bytes) -> PlantFile:
    """The plant file in `raw` (TOML), or BadPlantFile in one line."""
    if len(raw) > MAX_FILE_BYTES:
        raise BadPlantFile(f"{len(raw)} bytes, more than a plant file's {MAX_FILE_BYTES}")
    try:
        table = load_toml(raw.decode())
    except UnicodeDecodeError:
        raise BadPlantFile("not text") from None
    except tomllib.TOMLDecodeError as error:
        raise BadPlantFile(f"not TOML: {error}") from None
    except BadDocument as error:
        raise BadPlantFile(str(error)) from None
    # A plant of a robot this installation lacks is refused by who reads it (the command line:
    # gainfarm.cli.options.plant_file), naming the robots it has; the contract checks the form.
    try:
        return PlantFile.model_validate(table)
    except ValidationError as error:
        raise BadPlantFile(describe(error)) from None
