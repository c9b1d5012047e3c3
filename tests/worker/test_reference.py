import mujoco
import numpy as np
import pytest

from models import compile_model
from schemas import CONTROL_PERIOD, ModelSpec, TrajectorySpec
from worker.ik import UnreachablePath
from worker.reference import reference_for


@pytest.mark.parametrize("kind", ["spiral", "random", "pyramid"])
def test_reference_puts_the_flange_on_the_path_within_the_joint_limits(kind):
    reference = reference_for(TrajectorySpec(kind=kind, duration=3.0))
    model = compile_model(ModelSpec(joints="rigid"))
    data = mujoco.MjData(model)
    worst = 0.0
    for q, target in zip(reference.q[::25], reference.ee[::25], strict=True):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        worst = max(worst, float(np.linalg.norm(data.site("flange").xpos - target)))
    assert worst < 1e-3
    assert np.all(reference.q >= model.jnt_range[:, 0])
    assert np.all(reference.q <= model.jnt_range[:, 1])
    # Continuous joint motion: no jumps between consecutive solutions.
    assert np.abs(np.diff(reference.q, axis=0)).max() < 0.02
    np.testing.assert_allclose(
        reference.qd[1:-1], np.gradient(reference.q, CONTROL_PERIOD, axis=0)[1:-1]
    )


def test_references_are_cached_and_read_only():
    spec = TrajectorySpec(duration=1.0)
    first = reference_for(spec)
    assert reference_for(TrajectorySpec(duration=1.0)) is first
    with pytest.raises(ValueError):
        first.q[0, 0] = 1.0


def test_gravity_feedforward_holds_the_reference_posture():
    reference = reference_for(TrajectorySpec(duration=1.0))
    # A2 carries most of the arm: tens of N·m, as at the home posture.
    assert 20 < abs(reference.gravity[0, 1]) < 80


def test_a_path_out_of_reach_is_a_clear_error():
    with pytest.raises(UnreachablePath, match="unreachable"):
        reference_for(TrajectorySpec(center=(1.5, 0.0, 0.4), duration=1.0))
