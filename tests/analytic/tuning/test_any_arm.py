"""Tuning a 6-joint arm (the UR5e): the search space, the variants, the config and the records
take the robot's joints, default gains, ranges and workspace, not the iiwa 14's."""

import numpy as np
import pytest
from pydantic import ValidationError

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.plants import BadUncertainty, Range, design, ranges, variants
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.models import resolve, robot_of
from gainfarm.schemas.gains import DEFAULT_GAINS, KD_RANGE, KP_RANGE
from gainfarm.schemas.robot import PlantSpec

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
