"""Sensor/actuator layer: the simulated cobot. Torques in, joint states out.

The robot's joint state is link-side: in the elastic variant each joint's angle is the sum of its
motor and spring hinges, and its motor angle is the motor hinge alone. The maps below turn the
simulator's generalised coordinates into those angles, so that the tick loop can fold them into
its gain matrices and the log can be computed in bulk after the episode.
"""

from collections.abc import Sequence
from functools import lru_cache

import mujoco
import numpy as np

from gainfarm.models import resolve, robot_of
from gainfarm.schemas.robot import LoadData, PlantSpec


class Plant:
    """One simulated arm, the robot `spec` names (rigid or elastic joints), with its state.

    `link_map` and `motor_map` are (joints, nq) matrices with q = link_map @ qpos and
    θ = motor_map @ qpos (the same for velocities: nq = nv, every joint is a hinge). For rigid
    joints the motor is geared rigidly to the link, so the two maps are equal.
    """

    def __init__(self, spec: PlantSpec) -> None:
        self.spec = spec = resolve(spec)
        self.robot = robot_of(spec)
        self.model = self.robot.build(spec)
        self.data = mujoco.MjData(self.model)
        self.substeps = spec.substeps
        self.link_map = _link_map(self.model, self.robot.joint_names)
        driven = self.model.actuator_trnid[:, 0]  # the hinge each motor turns, base to flange
        self.motor_map = np.zeros_like(self.link_map)
        self.motor_map[np.arange(len(driven)), self.model.jnt_qposadr[driven]] = 1.0
        self.torque_limits = self.model.actuator_ctrlrange[:, 1].copy()
        self.joint_range = self.model.jnt_range[driven].copy()
        dofs = self.model.jnt_dofadr[driven]
        stride = int(dofs[1] - dofs[0])
        if not np.array_equal(dofs, dofs[0] + stride * np.arange(len(dofs))):
            raise AssertionError("the motors' hinges are not evenly spaced in the model")
        # qfrc_applied[motor_dof_slice] is a view of the motors' generalised forces, in order
        self.motor_dof_slice = slice(int(dofs[0]), int(dofs[-1]) + 1, stride)
        self._driven_qpos = self.model.jnt_qposadr[driven]
        self.flange = self.model.site(self.robot.flange).id

    @property
    def joints(self) -> int:
        """The robot's joint count."""
        return len(self.robot.joint_names)

    @property
    def elastic(self) -> bool:
        return self.spec.joints == "flexible"

    @property
    def feedback_map(self) -> np.ndarray:
        """The map to the angles the PD feeds back: link-side, or motor-side."""
        return self.link_map if self.spec.feedback == "link" else self.motor_map

    def reset(self, q: np.ndarray) -> None:
        """At rest at link angles `q`, springs relaxed (each motor angle equals its link angle)."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self._driven_qpos] = q
        mujoco.mj_forward(self.model, self.data)

    def joint_torque(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """(n, joints) torque each elastic joint transmits from motor to link,
        K (θ − q) + D (θ̇ − q̇): what its torque sensor measures, and what drives the link side."""
        stiffness = np.asarray(self.spec.stiffness)
        damping = np.asarray(self.spec.spring_damping)
        spring = (self.motor_map - self.link_map).T  # θ − q: minus the spring hinge's angle
        deflection, rate = qpos @ spring, qvel @ spring
        return stiffness * deflection + damping * rate


def _link_map(model: mujoco.MjModel, joint_names: tuple[str, ...]) -> np.ndarray:
    """Sum every hinge of link i (its one hinge, or motor + spring) into joint i's angle. A
    joint's name may hold underscores (the UR5e's shoulder_pan_joint): the flexible variant's
    suffixes are taken off, not split at."""
    link_map = np.zeros((len(joint_names), model.nq))
    for j in range(model.njnt):
        name = model.joint(j).name.removesuffix("_motor").removesuffix("_spring")
        link_map[joint_names.index(name), model.jnt_qposadr[j]] = 1.0
    return link_map


class RobotGravity:
    """The robot's own model of the arm's gravity, as KUKA's controller adds it in FRI torque
    mode: the rigid arm its robot declares it knows (`Robot.gravity_spec`: for the iiwa 14, the
    plant's named inertial set, which need not be the simulated plant's true masses), evaluated
    at measured link angles.

    Write the angles into `angles` (a view of the model's qpos), then `torque(out)` puts the
    torque holding them against gravity into `out`: three calls into MuJoCo (kinematics, centres
    of mass, Newton-Euler with zero velocity), some 5 µs, the tick loop's per world.
    """

    def __init__(self, spec: PlantSpec) -> None:
        robot = robot_of(spec)
        self.model = robot.build(robot.gravity_spec(spec))
        self.data = mujoco.MjData(self.model)
        self.angles = self.data.qpos

    def torque(self, out: np.ndarray) -> None:
        # qvel stays zero and mj_comVel is never called, so the bias force is gravity alone.
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_rne(self.model, self.data, 0, out)

    def at(self, angles: np.ndarray) -> np.ndarray:
        """(n, joints) N·m holding each row of link angles `angles` against gravity."""
        torques = np.empty_like(angles, dtype=float)
        for row, torque in zip(angles, torques, strict=True):
            self.angles[:] = row
            self.torque(torque)
        return torques


class ArmsGravity:
    """RobotGravity for many arms at once, as a stack of episodes steps: one model holding the
    rigid arm of each, side by side, so that one call each of kinematics, centres of mass and
    Newton-Euler computes them all (some 1 µs an arm, a third of an arm's own calls or of a
    Batch's per-world cost). An arm's arithmetic reads only its own bodies, so each gets the
    same bits as its RobotGravity (tests/worker/test_plant.py).

    Write each arm's angles into its row of `angles`, `compute()`, read its row of `torque`."""

    def __init__(self, specs: Sequence[PlantSpec]) -> None:
        # Keyed by what the robot's model knows of each arm (cheaper than a gravity_spec each:
        # a stack makes one per block of episodes). A stack's arms are of one robot.
        self.model = _arms(tuple((spec.robot, spec.inertials, _told(spec)) for spec in specs))
        self.data = mujoco.MjData(self.model)
        joints = len(robot_of(specs[0]).joint_names)
        self.angles = self.data.qpos.reshape(len(specs), joints)
        self._out = np.zeros(self.model.nv)
        self.torque = self._out.reshape(len(specs), joints)

    def compute(self) -> None:
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_rne(self.model, self.data, 0, self._out)


@lru_cache(maxsize=16)
def _arms(arms: tuple[tuple[str, str, LoadData | None], ...]) -> mujoco.MjModel:
    """One rigid arm per (robot, inertial set, told load) given, in order, their joints' angles
    one after another: each the robot's model of its arm (gravity_spec). Only the bodies'
    inertials count: shapes, sites and motors are left out of all but the first (whose options
    the model keeps: attaching an arm with other options would warn)."""
    known = [_known(*arm) for arm in arms]
    whole, *others = (robot_of(spec).describe(gravity_spec(spec)) for spec in known)
    for index, arm in enumerate(others, start=1):
        for part in [*arm.geoms, *arm.sites, *arm.actuators]:
            arm.delete(part)
        whole.worldbody.add_frame().attach_body(arm.worldbody.first_body(), f"arm{index}/", "")
    return whole.compile()


def _told(spec: PlantSpec) -> LoadData | None:
    return None if spec.load is None else spec.load.told


def _known(robot: str, inertials: str, load: LoadData | None) -> PlantSpec:
    return PlantSpec(robot=robot, inertials=inertials, load=load)  # type: ignore[arg-type]


def gravity_spec(spec: PlantSpec) -> PlantSpec:
    """The rigid arm whose gravity the robot's model of `spec` computes, as its robot declares it
    (for the iiwa 14: its inertial set and the load it is told, models.iiwa14.gravity_spec)."""
    return robot_of(spec).gravity_spec(spec)
