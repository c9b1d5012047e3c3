"""Sensor/actuator layer: the simulated cobot. Torques in, link-side joint states out."""

import mujoco
import numpy as np

from models import FLANGE, compile_model
from schemas.robot import JOINT_NAMES, ModelSpec


class Plant:
    """One simulated iiwa 14 (rigid or elastic joints) with its state.

    The robot's joint state is link-side: in the elastic variant each joint's angle is the sum of
    its motor and spring hinges. `link_map` is the (7, nq) matrix with q = link_map @ qpos (and
    q̇ = link_map @ qvel); the tick loop folds it into its gain matrices.
    """

    def __init__(self, spec: ModelSpec) -> None:
        self.spec = spec
        self.model = compile_model(spec)
        self.data = mujoco.MjData(self.model)
        self.substeps = spec.substeps
        self.link_map = _link_map(self.model)
        self.torque_limits = self.model.actuator_ctrlrange[:, 1].copy()
        driven = self.model.actuator_trnid[:, 0]  # the hinge each motor turns, A1..A7
        self.joint_range = self.model.jnt_range[driven].copy()
        self._driven_qpos = self.model.jnt_qposadr[driven]
        self.flange = self.model.site(FLANGE).id

    def reset(self, q: np.ndarray) -> None:
        """At rest at link angles `q`, springs relaxed (each motor angle equals its link angle)."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self._driven_qpos] = q
        mujoco.mj_forward(self.model, self.data)


def _link_map(model: mujoco.MjModel) -> np.ndarray:
    """Sum every hinge of link i (its one hinge, or motor + spring) into joint i's angle."""
    link_map = np.zeros((len(JOINT_NAMES), model.nq))
    for j in range(model.njnt):
        joint_index = JOINT_NAMES.index(model.joint(j).name.split("_")[0])
        link_map[joint_index, model.jnt_qposadr[j]] = 1.0
    return link_map
