"""--payload and --payload-com, the load the robot is told, through the real command lines."""

import subprocess
import sys
from pathlib import Path

import pytest

from gainfarm.analytic.calibration.twin import write_text
from gainfarm.analytic.commands.work.common import plants_from
from gainfarm.cli import options, values
from gainfarm.models import resolve
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.plant_file import PlantFile
from gainfarm.schemas.robot import MAX_LOAD_OFFSET, RATED_PAYLOAD, LoadData, PlantSpec
from tests.helpers import analytic

WORKER = [sys.executable, "-m", "gainfarm.worker", "episode"]
SHORT = ["--trajectory", "fourier", "--duration", "0.3"]


def test_the_options_limits_are_the_contracts() -> None:
    assert options.RATED_PAYLOAD == RATED_PAYLOAD
    assert options.MAX_LOAD_OFFSET == MAX_LOAD_OFFSET


@pytest.mark.parametrize(
    ("arguments", "says"),
    [
        (["--payload", "-1"], "--payload: -1 kg is not a load from 0 to the rated 14 kg"),
        (["--payload", "nan"], "--payload: nan kg is not a load"),
        (["--payload", "14.5"], "--payload: 14.5 kg is not a load"),
        (["--payload", "five"], "'--payload': 'five' is not a valid float"),
        (["--payload", "5", "--payload-com", "0,0"], "--payload-com: expected 3 numbers, got 2"),
        (["--payload", "5", "--payload-com", "0,0,x"], "--payload-com: expected 3 comma-sep"),
        (["--payload", "5", "--payload-com", "0,nan,0"], "--payload-com: '0,nan,0': each"),
        (["--payload", "5", "--payload-com", "0,0,0.9"], "within 0.5 m of the flange's centre"),
        (["--payload-com", "0,0,0.1"], "--payload-com: give the load's mass with --payload"),
    ],
)
@pytest.mark.parametrize("command", ["start", "batch", "experiment", "calibrate", "episode"])
def test_a_bad_load_is_one_line_naming_the_option_and_writes_nothing(
    tmp_path: Path, command: str, arguments: list[str], says: str
) -> None:
    if command == "episode":
        done = subprocess.run(
            [*WORKER, *SHORT, "--out", "ep.mcap", *arguments],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
        )
    elif command == "calibrate":  # refused before its logs are read
        done = analytic(command, *arguments, "nothing.mcap", cwd=tmp_path)
    elif command == "experiment":
        done = analytic(command, "speed", "--local", "--out", "x", *arguments, cwd=tmp_path)
    else:
        done = analytic(command, "--local", *SHORT, *arguments, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert says in done.stderr and len(done.stderr.splitlines()) == 1, done.stderr
    assert "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_an_episode_runs_on_the_load_it_was_told(tmp_path: Path) -> None:
    command = [*WORKER, *SHORT, "--payload", "5", "--payload-com", "0,0.01,0.1"]
    done = subprocess.run([*command, "--out", str(tmp_path / "ep.mcap")], capture_output=True)
    assert done.returncode == 0, done.stderr
    model = read_episode(tmp_path / "ep.mcap").metadata.spec.plant
    assert model == resolve(PlantSpec(load=LoadData(mass=5.0, com=(0.0, 0.01, 0.1))))
    # --payload 0: told of none, the very spec (and JSON) of no option at all.
    done = subprocess.run([*WORKER, *SHORT, "--payload", "0", "--out", str(tmp_path / "0.mcap")])
    assert done.returncode == 0
    assert read_episode(tmp_path / "0.mcap").metadata.spec.plant == resolve(PlantSpec())


def twin(path: Path, payload: float, load: LoadData | None = None) -> Path:
    """A calibrated plant file whose fit found `payload` kg at the flange, ±0.5 kg (not below 0),
    on a plant told of `load`."""
    plant = PlantSpec(payload=payload, load=load)
    fitted = {
        "field": "payload",
        "absolute": True,
        "draw": "uniform",
        "low": max(payload - 0.5, 0.0),
        "high": payload + 0.5,
        "why": "calibrated",
    }
    calibration = {"payload": {"fit": [payload]}}
    path.write_text(
        write_text(PlantFile(plant=plant, uncertainty={"payload": fitted}, calibration=calibration))
    )
    return path


def test_a_twins_calibrated_payload_is_the_load_the_robot_is_told(tmp_path: Path) -> None:
    file = str(twin(tmp_path / "twin.toml", 2.0))
    nominal = values.with_load(values.model_spec(file), None, None, file)
    assert nominal.load == LoadData(mass=2.0) and nominal.payload == 0.0
    # Its variants draw the fit's range as the told load's error, nothing untold.
    for plant in plants_from(16, None, nominal, 1, plant=file):
        assert plant.payload == 0.0 and plant.load is not None and plant.load.mass == 2.0
        assert 0.75 <= plant.load.mass_scale <= 1.25  # (2 ± 0.5) / 2
    # --payload tells another load: the file's payload stays untold, its range as it was.
    other = values.with_load(values.model_spec(file), 1.0, None, file)
    assert other.load == LoadData(mass=1.0) and other.payload == 2.0
    assert all(1.5 <= p.payload <= 2.5 for p in plants_from(8, None, other, 1, plant=file))
    # A plant file no calibration weighed keeps its payload untold.
    plain = tmp_path / "plain.toml"
    plain.write_text(write_text(PlantFile(plant=PlantSpec(payload=2.0))))
    kept = values.with_load(values.model_spec(str(plain)), None, None, str(plain))
    assert kept == PlantSpec(payload=2.0)
    # Nor does one whose fit cannot tell its payload from none (its range reaches 0).
    light = str(twin(tmp_path / "light.toml", 0.3))
    assert values.with_load(values.model_spec(light), None, None, light) == PlantSpec(payload=0.3)


def test_a_twins_payload_joins_the_load_its_arm_was_told_of(tmp_path: Path) -> None:
    # Calibrated on an arm told of 4 kg 10 cm out: the 1 kg more the logs found at the flange's
    # centre is told with it, one load at their common centre (all gravity reads).
    file = str(twin(tmp_path / "twin.toml", 1.0, LoadData(mass=4.0, com=(0.0, 0.0, 0.1))))
    nominal = values.with_load(values.model_spec(file), None, None, file)
    assert nominal.payload == 0.0 and nominal.load is not None
    assert nominal.load.mass == 5.0 and nominal.load.com == pytest.approx((0.0, 0.0, 0.08))
    for plant in plants_from(16, None, nominal, 1, plant=file):
        assert 0.9 - 1e-6 <= plant.load.mass_scale <= 1.1 + 1e-6  # (4 + 1 ± 0.5) / 5
