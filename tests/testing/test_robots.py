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
FAULTS = [
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
