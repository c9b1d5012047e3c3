"""The robots' conformance kit catches each fault it is for: a robot that is the iiwa 14 but for
one broken fact fails that fact's check, saying so."""

import dataclasses
import re
from typing import Any

import pytest

from gainfarm import plugins
from gainfarm.models import iiwa14
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import PlantSpec
from gainfarm.testing import robots as kit


class Broken:
    """The iiwa 14 under another name, with `changes` to its declared facts."""

    def __init__(self, name: str = "broken-arm", **changes: Any) -> None:
        self.name = name
        self.joint_names = iiwa14.ROBOT.joint_names
        self.limits = iiwa14.ROBOT.limits
        self.default_gains = iiwa14.ROBOT.default_gains
        self.workspace = iiwa14.ROBOT.workspace
        self.flange = iiwa14.ROBOT.flange
        self.plant_defaults = iiwa14.ROBOT.plant_defaults
        self.torque_interface = iiwa14.ROBOT.torque_interface
        self.inertial_sets = iiwa14.ROBOT.inertial_sets
        self.rated_payload = iiwa14.ROBOT.rated_payload
        self.uncertainty = iiwa14.ROBOT.uncertainty
        self.gravity_inertials: str | None = None
        for key, value in changes.items():
            setattr(self, key, value)

    def build(self, spec: PlantSpec) -> Any:
        return iiwa14.compile_model(spec)

    def describe(self, spec: PlantSpec) -> Any:
        return iiwa14.build_spec(spec)

    def gravity_spec(self, spec: PlantSpec) -> PlantSpec:
        known = iiwa14.gravity_spec(spec)
        if self.gravity_inertials is None:
            return known
        return known.model_copy(update={"inertials": self.gravity_inertials})


def test_an_unbroken_copy_passes_every_check_and_is_forgotten_after() -> None:
    kit.check_robot(Broken())
    assert "broken-arm" not in plugins.names(plugins.ROBOTS)


LIMITS = iiwa14.ROBOT.limits
DEFAULTS = iiwa14.ROBOT.plant_defaults
FAULTS = [
    (
        kit.check_members,
        {"plant_defaults": dataclasses.replace(DEFAULTS, coulomb=DEFAULTS.coulomb[:6])},
        "plant defaults' coulomb: 6 for 7 joints",
    ),
    (
        kit.check_members,
        {"plant_defaults": dataclasses.replace(DEFAULTS, stiffness="firm")},
        "default stiffness 'firm': no preset",
    ),
    (kit.check_members, {"rated_payload": 0.0}, "rated_payload 0.0"),
    (kit.check_members, {"inertial_sets": ()}, "inertial_sets (): one at least"),
    (
        kit.check_members,
        {"uncertainty": iiwa14.ROBOT.uncertainty.parent.joinpath("no-such-ranges.toml")},
        "no-such-ranges.toml",
    ),
    (
        # A robot fifty times slower than the iiwa: its default spiral (2.6 s on the iiwa, 128 s
        # on it) would take 142 s to stay within 0.9 of its speed limits, beyond any
        # trajectory's 120.
        kit.check_references,
        {"limits": dataclasses.replace(LIMITS, speed=tuple(0.02 * v for v in LIMITS.speed))},
        "the default spiral: 142 s to stay within 0.9 of the limits, beyond 120 s",
    ),
    (
        kit.check_references,
        {
            "workspace": dataclasses.replace(
                iiwa14.WORKSPACE, center=(1.2, 0.0, 0.35), high=(1.2, 0.15, 0.45)
            )
        },
        "the default spiral: the path is unreachable",
    ),
    (kit.check_name, {"name": "Broken Arm"}, "robot name 'Broken Arm'"),
    (kit.check_limits, {"limits": dataclasses.replace(LIMITS, speed=LIMITS.speed[:6])}, "speed"),
    (kit.check_limits, {"limits": dataclasses.replace(LIMITS, torque=(0.0,) * 7)}, "torque"),
    (
        kit.check_limits,
        {"default_gains": PDGains.model_construct(kp=(1.0,) * 6, kd=(1.0,) * 6)},
        "default kp",
    ),
    (
        kit.check_limits,
        {"workspace": dataclasses.replace(iiwa14.WORKSPACE, home=(0.0, 2.5, 0, 0, 0, 0, 0))},
        "A2 beyond the position limit",
    ),
    (
        kit.check_builds,
        {"limits": dataclasses.replace(LIMITS, torque=(300.0,) * 7)},
        "rigid: motors' ctrlrange",
    ),
    (kit.check_builds, {"joint_names": ("A1", "A2", "A3")}, "rigid: 7 motors for 3 joints"),
    (
        kit.check_holds_still,
        {"default_gains": PDGains(kp=(0.0,) * 7, kd=(0.0,) * 7)},
        "rigid: A4 strays 0.02 rad from home (at most 0.005 rad)",
    ),
    (kit.check_gravity, {"gravity_inertials": "cad"}, "gravity model at"),
    (
        kit.check_workspace,
        {"workspace": dataclasses.replace(iiwa14.WORKSPACE, high=(1.2, 0.15, 0.45))},
        "unreachable",
    ),
]


@pytest.mark.parametrize(
    ("check", "changes", "said"),
    FAULTS,
    ids=[f"{check.__name__}-{said}" for check, _, said in FAULTS],
)
def test_a_broken_fact_fails_its_check_saying_what(check, changes, said) -> None:
    with pytest.raises(AssertionError, match=re.escape(said)):
        check(Broken(**changes))
    assert "broken-arm" not in plugins.names(plugins.ROBOTS)


def test_a_robot_under_a_name_taken_here_is_refused() -> None:
    with pytest.raises(AssertionError, match="'iiwa14' names another robot here"):
        kit.check_builds(Broken(name="iiwa14"))
