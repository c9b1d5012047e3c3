"""The plant's parts that the tick loop shares among episodes."""

import numpy as np

from gainfarm.schemas.robot import PlantSpec
from gainfarm.worker.plant import ArmsGravity, RobotGravity


def test_many_arms_gravity_gives_each_arm_the_bits_its_own_model_gives() -> None:
    # Arms of every inertial set side by side, one of them twice, at angles across their range.
    specs = [PlantSpec(inertials=name) for name in ("open", "menagerie", "cad", "open")]
    angles = np.random.default_rng(3).uniform(-2.0, 2.0, (50, len(specs), 7))
    arms = ArmsGravity(specs)
    for tick in angles:
        arms.angles[:] = tick
        arms.compute()
        alone = [RobotGravity(spec).at(row[None])[0] for spec, row in zip(specs, tick, strict=True)]
        assert np.array_equal(arms.torque, np.stack(alone))
    # The inertial sets differ, so each arm's torque is its own set's, not the first arm's.
    assert len({arms.torque[index].tobytes() for index in range(3)}) == 3


def test_many_arms_gravity_is_one_model_of_rigid_arms_without_shapes() -> None:
    arms = ArmsGravity([PlantSpec()] * 5)
    assert arms.model.nq == arms.model.nv == 5 * 7
    assert arms.model.nu == 7  # the first arm's motors; the others' are left out
    assert arms.model.ngeom == ArmsGravity([PlantSpec()]).model.ngeom  # likewise its shapes
