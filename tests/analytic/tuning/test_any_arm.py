"""Tuning a 6-joint arm (the UR5e): the search space, the variants, the config and the records
take the robot's joints, default gains, ranges and workspace, not the iiwa 14's."""

import numpy as np
import pytest
from pydantic import ValidationError

from gainfarm.analytic.compose import defaults_hold
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.plants import (
    BadUncertainty,
    Range,
    corner,
    design,
    held_design,
    ranges,
    variants,
)
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.models import resolve, robot_of
from gainfarm.schemas.gains import DEFAULT_GAINS, KD_RANGE, KP_RANGE
from gainfarm.schemas.limits import Limits
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec

UR5E = PlantSpec(robot="ur5e")


def test_the_search_space_is_two_gains_per_joint_around_the_robots_defaults() -> None:
    defaults = robot_of("ur5e").default_gains
    space = SearchSpace.around(defaults)
    assert space.joints == 6 and space.lower.shape == space.upper.shape == (12,)
    assert np.allclose(
        10**space.lower,
        [k * KP_RANGE[0] for k in defaults.kp] + [k * KD_RANGE[0] for k in defaults.kd],
    )
    middle = space.gains(np.log10(np.array(defaults.kp + defaults.kd)))
    assert len(middle.kp) == len(middle.kd) == 6
    assert np.allclose(middle.kp + middle.kd, defaults.kp + defaults.kd)
    assert SearchSpace() == SearchSpace.around(DEFAULT_GAINS)  # the iiwa 14's, as it was


def test_a_ur5e_run_config_takes_its_robots_centre_gains_and_joints() -> None:
    config = RunConfig(plant=UR5E, pop=8)
    arm = robot_of("ur5e")
    assert config.trajectories[0].center == arm.workspace.center
    assert config.default_gains == arm.default_gains and config.space.joints == 6
    assert config.plant == resolve(UR5E)  # written out, six numbers a field
    assert len(config.plant.stiffness) == 6
    with pytest.raises(ValueError, match="7 pairs for ur5e's 6 joints"):
        config.episode_spec(DEFAULT_GAINS, 0)
    with pytest.raises(ValidationError, match="a variant of iiwa14, not of the run's robot ur5e"):
        RunConfig(plant=UR5E, plants=(PlantSpec(),))


def test_ur5e_variants_draw_six_numbers_a_joint_field_from_its_own_ranges() -> None:
    nominal = resolve(UR5E)
    drawn = variants(UR5E, 4, seed=1)
    assert drawn == variants(UR5E, 4, seed=1)
    table = ranges(robot="ur5e")
    for plant in drawn:
        assert plant.robot == "ur5e"
        for field in ("stiffness", "rotor_inertia", "mass_scale", "spring_damping"):
            assert len(getattr(plant, field)) == 6, field
        if "stiffness" in table:
            item = table["stiffness"]
            factors = np.divide(plant.stiffness, nominal.stiffness)
            assert (factors >= np.min(item.low) - 1e-12).all()
            assert (factors <= np.max(item.high) + 1e-12).all()
    heavy, light = design(UR5E, 2, seed=0)
    assert heavy.robot == light.robot == "ur5e" and heavy != light


def test_a_per_joint_range_of_another_joint_count_is_refused_naming_it() -> None:
    seven = Range(
        field="stiffness", per_joint=True, draw="log", low=(0.5,) * 7, high=(2.0,) * 7, why="w"
    )
    with pytest.raises(BadUncertainty, match=r"stiff: 7 numbers per bound for ur5e's 6 joints"):
        variants(UR5E, 1, seed=0, uncertainty={"stiff": seven})
    assert len(variants(PlantSpec(), 1, seed=0, uncertainty={"stiff": seven})) == 1  # the iiwa's


def test_a_corner_part_of_the_way_moves_each_range_part_of_the_way() -> None:
    nominal = resolve(UR5E)
    ends = {"stiffness": "high", "delay": "high", "payload": "high"}
    table = ranges(robot="ur5e")
    full, half = corner(UR5E, ends, table), corner(UR5E, ends, table, share=0.5)
    assert np.allclose(np.divide(full.stiffness, nominal.stiffness), table["stiffness"].high)
    assert np.allclose(np.divide(half.stiffness, nominal.stiffness), table["stiffness"].high ** 0.5)
    assert half.payload == pytest.approx(table["payload"].high / 2)  # absolute: from 0 kg
    assert half.delay == round((nominal.delay + table["delay"].high) / 2)
    assert corner(UR5E, ends, table, share=1.0) == full


def test_a_held_design_moves_a_corner_back_until_the_default_gains_hold_there() -> None:
    nominal = resolve(UR5E)
    asked: list[PlantSpec] = []

    def holds(plant: PlantSpec) -> bool:  # as if the default gains broke a limit on any plant
        asked.append(plant)  # whose springs are more than 1.3 times the nominal's
        return max(np.divide(plant.stiffness, nominal.stiffness)) <= 1.3

    plants, shares = held_design(UR5E, 3, seed=2, holds=holds)
    # heavy: softer springs, held at once; light: 2x stiffer, then 1.41x, then 1.19x
    assert shares == (1.0, 0.25) and len(asked) == 4
    assert plants[:2] == design(UR5E, 2, seed=2, shares=shares)
    assert plants[2] == variants(UR5E, 1, seed=2)[0]  # the random draws as they were
    assert np.allclose(np.divide(plants[1].stiffness, nominal.stiffness), 2.0**0.25)
    assert held_design(PlantSpec(), 2, seed=2, holds=lambda _: True) == (
        design(PlantSpec(), 2, seed=2),
        (1.0, 1.0),
    )


def test_the_default_gains_hold_on_the_nominal_plant_not_under_a_limit_they_break() -> None:
    spiral = (TrajectorySpec(),)
    assert defaults_hold(spiral, Limits(), ("f_acc", "f_t"))(UR5E)
    too_slow = Limits(speed=0.01)  # a speed limit no motion keeps to
    assert not defaults_hold(spiral, too_slow, ("f_acc", "f_t"))(UR5E)
