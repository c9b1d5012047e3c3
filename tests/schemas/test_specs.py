import math

import pytest
from pydantic import ValidationError

from gainfarm.schemas import EpisodeSpec, PDGains, PlantSpec, TrajectorySpec
from gainfarm.schemas.wire import describe

SEVEN = (1.0,) * 7


@pytest.mark.parametrize(
    "kp",
    [(1.0,) * 6, (1.0,) * 8, (*SEVEN[:6], math.nan), (*SEVEN[:6], -1.0), (*SEVEN[:6], math.inf)],
)
def test_gains_reject_wrong_count_nan_negative_and_infinite(kp):
    with pytest.raises(ValidationError):
        PDGains(kp=kp, kd=SEVEN)


def test_gains_accept_seven_non_negative_numbers():
    gains = PDGains(kp=SEVEN, kd=(0.0,) * 7)
    assert gains.kp == SEVEN and gains.kd == (0.0,) * 7


@pytest.mark.parametrize("duration", [0.0, -1.0, 0.05, 1e6, math.nan, math.inf])
def test_trajectory_rejects_absurd_durations(duration):
    with pytest.raises(ValidationError):
        TrajectorySpec(duration=duration)


@pytest.mark.parametrize("kind", ["", "Circle", "9lives", "a/b", "x" * 33, "spiral*"])
def test_trajectory_rejects_a_kind_that_is_no_plugin_name(kind):
    with pytest.raises(ValidationError):
        TrajectorySpec(kind=kind)


def test_a_kind_of_the_right_form_is_the_workers_to_know():
    # A plug-in's kind (gainfarm.trajectories): the contract checks the name, a worker without
    # the plug-in refuses the job (tests/test_plugins.py).
    assert TrajectorySpec(kind="circle").kind == "circle"


def test_ticks_cover_both_ends_of_the_duration():
    assert TrajectorySpec(duration=5.0).ticks == 2501
    assert TrajectorySpec(duration=3.0).ticks == 1501


def test_a_plant_leaves_its_per_joint_numbers_to_its_robot_and_resolve_writes_them_out():
    from gainfarm.models import PlantError, resolve

    spec = PlantSpec()
    assert spec.joints == "flexible" and spec.stiffness is None and spec.mass_scale is None
    written = resolve(spec)
    assert len(written.stiffness) == len(written.spring_damping) == len(written.rotor_inertia) == 7
    assert written.mass_scale == (1.0,) * 7 and resolve(written) == written
    assert (
        resolve(PlantSpec(stiffness="soft")).stiffness
        == (5000.0,) * 2 + (4000.0,) * 2 + (2000.0,) * 3
    )
    with pytest.raises(PlantError, match=r"^stiffness: 6 numbers for iiwa14's 7 joints \(A1, "):
        resolve(PlantSpec(stiffness=(1e4,) * 6))
    with pytest.raises(PlantError, match=r"^inertials: iiwa14 has no set 'urdf'"):
        resolve(PlantSpec(inertials="urdf"))
    with pytest.raises(ValidationError):
        PlantSpec(substeps=0)
    with pytest.raises(ValidationError):
        PlantSpec(stiffness=(0.0,) * 7)
    with pytest.raises(ValidationError, match="rotor_inertia must be positive"):
        PlantSpec(rotor_inertia=(0.4, 0.4, 0.3, 0.3, 0.1, 0.1, 0.0))
    assert PlantSpec(joints="rigid", rotor_inertia=(0.0,) * 7).joints == "rigid"


def test_the_named_plants_differ_only_where_they_say():
    from gainfarm.schemas.robot import IDEAL_PLANT, REALISTIC_PLANT, STIFFNESS_PRESETS

    assert IDEAL_PLANT.ideal and not REALISTIC_PLANT.ideal
    from gainfarm.models import resolve

    assert resolve(IDEAL_PLANT).stiffness == STIFFNESS_PRESETS["soft"]
    assert resolve(REALISTIC_PLANT).stiffness == STIFFNESS_PRESETS["medium"]
    assert (REALISTIC_PLANT.feedback, REALISTIC_PLANT.delay) == ("motor", 1)
    assert REALISTIC_PLANT.friction is not None and not REALISTIC_PLANT.sensors.exact


def test_specs_are_hashable_and_round_trip_through_json():
    spec = EpisodeSpec(gains=PDGains(kp=SEVEN, kd=SEVEN))
    again = EpisodeSpec.model_validate_json(spec.model_dump_json())
    assert again == spec and hash(again) == hash(spec)


def test_describe_names_the_field_and_counts_the_rest():
    with pytest.raises(ValidationError) as caught:
        PDGains(kp=(math.nan,) * 7, kd=(-1.0,) * 7)
    message = describe(caught.value)
    assert message.startswith("kp.0:")
    assert "more problems" in message
    assert "\n" not in message


def test_a_told_load_is_left_out_of_the_json_of_every_spec_told_of_none():
    import json

    from gainfarm.schemas.robot import PLANTS, LoadData

    for plant in PLANTS.values():  # the JSON of every spec from before: no key added
        assert "load" not in json.loads(plant.model_dump_json())
    loaded = PlantSpec(load=LoadData(mass=5.0, com=(0.0, 0.0, 0.1)))
    again = PlantSpec.model_validate_json(loaded.model_dump_json())
    assert again == loaded and hash(again) == hash(loaded)
    # A spec written before the interface was a choice (every field then, none added since)
    # still reads as the plain torque interface it ran on.
    earlier = json.loads(PlantSpec().model_dump_json())
    for added in ("interface", "payload", "mass_scale"):
        del earlier[added]
    assert PlantSpec.model_validate(earlier).interface == "torque"


@pytest.mark.parametrize(
    "load",
    [
        {"mass": -1.0},
        {"mass": 0.0},
        {"mass": math.nan},
        {"mass": 14.5},
        {"mass": 1.0, "com": (0.0, 0.0, 0.6)},
        {"mass": 1.0, "com": (0.0, math.nan, 0.0)},
        {"mass": 1.0, "mass_scale": 0.0},
    ],
)
def test_a_load_that_is_none_is_refused(load):
    from gainfarm.schemas.robot import LoadData

    with pytest.raises(ValidationError):
        LoadData(**load)
