"""A plant as a file: a calibrated twin of a real arm, or any plant a user writes down.

`analytic calibrate` writes one (TOML): the simulated plant it fitted to an arm's logs, how sure
it is of each number (its uncertainty, in the form of models/uncertainty.toml: robust tuning
draws its variants from it) and where the numbers came from. `--plant FILE` runs on it, on
`worker episode` as on the analytic commands; jobs carry the plant itself (a ModelSpec is every
number the simulation needs), so a worker needs no copy of the file. It lives in the contract
because the worker reads it and never imports the analytic layer; the uncertainty table is
checked by the analytic layer, which draws from it.
"""

import tomllib
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from gainfarm.schemas.robot import ModelSpec
from gainfarm.schemas.wire import describe

FORMAT = "gainfarm-plant/1"
MAX_FILE_BYTES = 1 << 20  # a plant is a few kB; anything larger is not one


class PlantFile(BaseModel):
    """What a plant file holds."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    format: str = Field(FORMAT, pattern=r"^gainfarm-plant/1$")
    plant: ModelSpec
    uncertainty: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="how far each calibrated number may be off: ranges in the form of "
        "models/uncertainty.toml, around this plant (empty: the shipped ranges)",
    )
    calibration: dict[str, Any] = Field(
        default_factory=dict, description="where the numbers came from: logs, fit, residuals"
    )


class BadPlantFile(ValueError):
    """Not a plant file, or not one this farm can simulate: the message says why, in one line."""


def read_plant_file(raw: bytes) -> PlantFile:
    """The plant file in `raw` (TOML), or BadPlantFile in one line."""
    if len(raw) > MAX_FILE_BYTES:
        raise BadPlantFile(f"{len(raw)} bytes, more than a plant file's {MAX_FILE_BYTES}")
    try:
        table = tomllib.loads(raw.decode())
    except UnicodeDecodeError:
        raise BadPlantFile("not text") from None
    except tomllib.TOMLDecodeError as error:
        raise BadPlantFile(f"not TOML: {error}") from None
    robot = table.get("plant", {}).get("robot") if isinstance(table.get("plant"), dict) else None
    if robot is not None and robot != ModelSpec.model_fields["robot"].default:
        # Said plainly: a twin of another arm is not a typo in one of its numbers.
        raise BadPlantFile(
            f"a plant of robot {robot!r}; this farm simulates "
            f"{ModelSpec.model_fields['robot'].default!r}"
        )
    try:
        return PlantFile.model_validate(table)
    except ValidationError as error:
        raise BadPlantFile(describe(error)) from None
