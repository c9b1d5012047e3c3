"""models/elastic.py: the step-ratio rule, for any arm's springs."""

import numpy as np
import pytest

from gainfarm.models import elastic, gen3
from gainfarm.models.robots import resolve
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD

JOINTS = ("a", "b")


def test_min_substeps_is_the_fewest_whose_every_ratio_is_within_the_bound() -> None:
    stiffness, damping, inertia = (40000.0, 2000.0), (10.0, 0.0), np.array([0.3, 0.001])
    substeps = elastic.min_substeps(stiffness, damping, inertia, JOINTS)
    ratios = elastic.step_ratios(stiffness, damping, inertia, CONTROL_PERIOD / substeps)
    assert ratios.max() <= elastic.MAX_STEP_RATIO
    fewer = elastic.step_ratios(stiffness, damping, inertia, CONTROL_PERIOD / (substeps - 1))
    assert fewer.max() > elastic.MAX_STEP_RATIO
    elastic.check_substeps(substeps, stiffness, damping, inertia, JOINTS)
    with pytest.raises(ValueError, match=rf"^substeps={substeps - 1} is too few for b's"):
        elastic.check_substeps(substeps - 1, stiffness, damping, inertia, JOINTS)


def test_a_spring_turning_nothing_without_damping_fits_no_step() -> None:
    with pytest.raises(ValueError, match="b's spring turns no inertia and has no damping"):
        elastic.min_substeps((100.0, 100.0), (1.0, 0.0), np.array([0.1, 0.0]), JOINTS)


def test_the_effective_inertia_is_at_most_the_rotor_s_and_the_link_s() -> None:
    # m = I B / (I + B) <= B: the spring turns the link against the rotor.
    spec = resolve(PlantSpec(robot="gen3"))
    model = gen3.ROBOT.build(spec)
    postures = (gen3.WORKSPACE.home,)
    inertia = elastic.effective_inertias(model, gen3.JOINT_NAMES, postures)
    assert (inertia > 0).all() and (inertia <= np.asarray(spec.rotor_inertia)).all()
    bigger = resolve(spec.model_copy(update={"rotor_inertia": (10.0,) * 7}))
    heavier = elastic.effective_inertias(gen3.ROBOT.build(bigger), gen3.JOINT_NAMES, postures)
    assert (heavier > inertia).all()
