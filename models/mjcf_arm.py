"""Any serial arm from an MJCF file, as a gainfarm.robots plug-in (schemas.robot.Robot).

`MjcfArm` reads the file (MuJoCo Menagerie's, vendored under models/menagerie/) and does to it
what models/iiwa14.py does to the iiwa's, found by the joints' names rather than by the bodies':
- the file's actuators (Menagerie's are position servos) become one torque motor per joint,
  named as the joint, its ctrlrange the data-sheet torque limit; its keyframes go (the flexible
  model has other coordinates), and contacts are disabled (nothing in this project touches
  anything, as with the iiwa);
- each hinge gets the data-sheet position limit, the rotor's reflected inertia as its armature and
  the viscous friction as its damping (the file's own damping and friction loss are dropped:
  Menagerie tunes them for its servos);
- the flexible variant (Spong's elastic joint, as the iiwa's): each hinge J becomes `J_motor`,
  driven by the motor, followed in the same body by `J_spring` about the same axis, with the
  spring's stiffness and damping;
- each link's mass_scale, the untold payload and the told load at the flange (solid spheres, as
  the iiwa's), the physics step CONTROL_PERIOD / substeps, autoreset disabled (a diverged episode
  stays diverged: it is data), and a flange site if the file has none.
`build` compiles once per PlantSpec (cached) and refuses springs the step cannot integrate
(models/elastic.py). Every number an arm declares is cited in models/README.md.
"""

import logging
from dataclasses import dataclass, field
from functools import lru_cache
from importlib.abc import Traversable

import mujoco
import numpy as np

from gainfarm.models import elastic
from gainfarm.models.robots import resolve
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import (
    JointLimits,
    LoadData,
    PlantDefaults,
    PlantSpec,
    TorqueInterface,
    Workspace,
)
from gainfarm.schemas.trajectory import CONTROL_PERIOD

log = logging.getLogger("gainfarm.models")

PAYLOAD_RADIUS = 0.05  # m: a payload is a solid sphere this big (assumption, as the iiwa's)


@dataclass(frozen=True, eq=False)  # hashed by identity: the compile cache keys on the arm
class MjcfArm:
    """A serial arm built from `mjcf`. `file_joints` are the file's hinge names, base to flange,
    when they are not `joint_names` (which the built model uses); the flange site is added on
    the last joint's body at `flange_pos`/`flange_quat` (its frame) if the file has none."""

    name: str
    mjcf: Traversable
    joint_names: tuple[str, ...]
    limits: JointLimits
    default_gains: PDGains
    workspace: Workspace
    torque_interface: TorqueInterface
    plant_defaults: PlantDefaults
    rated_payload: float  # kg
    uncertainty: Traversable  # its ranges file (models/uncertainty.toml's form)
    file_joints: tuple[str, ...] | None = None
    flange_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    flange_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    inertial_sets: tuple[str, ...] = ("menagerie",)
    flange: str = "flange"
    # Each hinge's (low, high) range, rad, where the maker's is not ±limits.position (the
    # Panda's joints 4 and 6); None: ±limits.position on every hinge.
    position_ranges: tuple[tuple[float, float], ...] | None = None
    # Postures at which the springs' modes are analysed, besides home: the arm at zero.
    spring_postures: tuple[tuple[float, ...], ...] = field(default=())

    def build(self, spec: PlantSpec) -> mujoco.MjModel:
        return _compile(self, resolve(spec))

    def describe(self, spec: PlantSpec) -> mujoco.MjSpec:
        return _describe(self, resolve(spec))

    def gravity_spec(self, spec: PlantSpec) -> PlantSpec:
        """The rigid arm the robot's own model knows: its inertial set and the load it is told,
        nothing else (rotors, springs and friction exert no gravity torque; the untold payload
        and the true masses it never knows)."""
        return PlantSpec(
            robot=spec.robot,
            joints="rigid",
            inertials=spec.inertials,
            friction=None,
            substeps=1,
            interface="torque",
            load=None if spec.load is None else spec.load.told,
        )

    def min_substeps(self, spec: PlantSpec) -> int:
        """The fewest physics steps per tick integrating `spec`'s springs well; 1 if rigid."""
        spec = resolve(spec)
        if spec.joints != "flexible":
            return 1
        model = _describe(self, spec).compile()
        return elastic.min_substeps(*self._springs(spec, model))

    def check_substeps(self, spec: PlantSpec, model: mujoco.MjModel) -> None:
        """ValueError, in one line, if `spec.substeps` is too few for its springs (`model`, its
        compiled plant)."""
        if spec.joints == "flexible":
            elastic.check_substeps(spec.substeps, *self._springs(spec, model))

    def _springs(
        self, spec: PlantSpec, model: mujoco.MjModel
    ) -> tuple[tuple[float, ...], tuple[float, ...], np.ndarray, tuple[str, ...]]:
        postures = (self.workspace.home, (0.0,) * len(self.joint_names), *self.spring_postures)
        inertia = elastic.effective_inertias(model, self.joint_names, postures)
        return spec.stiffness, spec.spring_damping, inertia, self.joint_names  # type: ignore[return-value]

    def __repr__(self) -> str:
        return f"<robot {self.name}>"


@lru_cache(maxsize=16)
def _compile(arm: MjcfArm, spec: PlantSpec) -> mujoco.MjModel:
    """`spec`'s compiled plant (resolved); cached: a worker runs thousands of episodes on one."""
    # An unstable simulation is data (the episode is flagged as diverged), not a warning for
    # stdout and a MUJOCO_LOG.TXT: MuJoCo's default. A handler already installed is kept.
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_log_warning)
    model = _describe(arm, spec).compile()
    arm.check_substeps(spec, model)
    return model


def _describe(arm: MjcfArm, spec: PlantSpec) -> mujoco.MjSpec:
    """The plant `spec` (resolved) describes, not yet compiled."""
    mj = mujoco.MjSpec.from_string(arm.mjcf.read_text())
    mj.option.timestep = CONTROL_PERIOD / spec.substeps
    # The iiwa's integrator (implicit in damping, so friction costs no stability).
    mj.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # A diverging episode must stay diverged (NaNs are data we detect), not be silently reset.
    mj.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    mj.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    for part in [*mj.actuators, *mj.keys]:
        mj.delete(part)
    hinges = _rename_joints(arm, mj)
    flange = _flange(arm, mj, hinges[-1].parent)
    for hinge, scale in zip(hinges, spec.mass_scale, strict=True):
        if scale != 1.0:  # the true link, heavier or lighter than its set says, its shape kept
            link = hinge.parent
            link.mass = link.mass * scale
            link.inertia = link.inertia * scale
    if spec.payload > 0:
        _add_sphere(flange, "payload", np.zeros(3), spec.payload)
    if spec.load is not None:
        _add_load(flange, spec.load)
    for i, hinge in enumerate(hinges):
        _drive(arm, mj, spec, i, hinge)
    return mj


def _rename_joints(arm: MjcfArm, mj: mujoco.MjSpec) -> list[mujoco.MjsJoint]:
    """The arm's hinges, base to flange, named as `arm.joint_names`; ValueError if the file has
    other joints or lacks one."""
    in_file = arm.file_joints or arm.joint_names
    if len(in_file) != len(arm.joint_names):
        raise ValueError(f"{arm.name}: {len(in_file)} file joints for {len(arm.joint_names)}")
    found = {joint.name for joint in mj.joints}
    if found != set(in_file):
        raise ValueError(f"{arm.mjcf.name}: joints {sorted(found)}, expected {list(in_file)}")
    hinges = [mj.joint(name) for name in in_file]
    for hinge, name in zip(hinges, arm.joint_names, strict=True):
        if hinge.type != mujoco.mjtJoint.mjJNT_HINGE:
            raise ValueError(f"{arm.mjcf.name}: {hinge.name} is not a hinge")
        hinge.name = name
    return hinges


def _flange(arm: MjcfArm, mj: mujoco.MjSpec, last: mujoco.MjsBody) -> mujoco.MjsSite:
    """The flange site: the file's, or one added on the last joint's body."""
    for site in mj.sites:
        if site.name == arm.flange:
            return site
    return last.add_site(name=arm.flange, pos=arm.flange_pos, quat=arm.flange_quat, size=[0.01])


def _drive(
    arm: MjcfArm, mj: mujoco.MjSpec, spec: PlantSpec, i: int, hinge: mujoco.MjsJoint
) -> None:
    """Joint i's limits, rotor and friction on its hinge, its torque motor, and its spring if
    the joints are flexible."""
    name, torque = arm.joint_names[i], arm.limits.torque[i]
    position = arm.limits.position[i]
    hinge.range = [-position, position] if arm.position_ranges is None else arm.position_ranges[i]
    hinge.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    hinge.armature = spec.rotor_inertia[i]
    hinge.frictionloss = 0.0  # the Coulomb part is the tick loop's, as for the iiwa
    damping = np.zeros_like(np.asarray(hinge.damping))  # MuJoCo 4: (linear, polynomial terms...)
    if spec.friction is not None:
        # Viscous friction on the motor side: joint damping, integrated implicitly (stable at any
        # step, free).
        damping[0] = spec.friction.viscous[i]
    hinge.damping = damping
    hinge.stiffness = np.zeros_like(np.asarray(hinge.stiffness))
    # Every parameter of a plain torque motor spelled out: left unset, the file's default
    # actuator class (Menagerie's is a position servo, force = kp (ctrl - q)) would fill them in.
    gain = np.zeros(mujoco.mjNGAIN)
    gain[0] = 1.0
    mj.add_actuator(
        name=name,
        target=name,
        trntype=mujoco.mjtTrn.mjTRN_JOINT,
        dyntype=mujoco.mjtDyn.mjDYN_NONE,
        gaintype=mujoco.mjtGain.mjGAIN_FIXED,
        gainprm=gain,
        biastype=mujoco.mjtBias.mjBIAS_NONE,
        biasprm=np.zeros(mujoco.mjNBIAS),
        ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
        ctrlrange=[-torque, torque],
        forcelimited=mujoco.mjtLimited.mjLIMITED_FALSE,
    )
    if spec.joints == "flexible":
        hinge.name = elastic.motor(name)
        mj.actuator(name).target = hinge.name
        stiffness = np.zeros_like(np.asarray(hinge.stiffness))
        stiffness[0] = spec.stiffness[i]
        spring_damping = np.zeros_like(np.asarray(hinge.damping))
        spring_damping[0] = spec.spring_damping[i]
        hinge.parent.add_joint(
            name=elastic.spring(name),
            type=mujoco.mjtJoint.mjJNT_HINGE,
            pos=hinge.pos,
            axis=hinge.axis,
            stiffness=stiffness,
            damping=spring_damping,
            limited=mujoco.mjtLimited.mjLIMITED_FALSE,
        )


def _add_load(flange: mujoco.MjsSite, load: LoadData) -> None:
    """The load, a solid sphere of its true mass centred on its centre of mass, given in the
    flange frame (the robot's own model is told its mass: `load.told`)."""
    offset = np.zeros(3)
    mujoco.mju_rotVecQuat(offset, np.asarray(load.com, dtype=float), np.asarray(flange.quat))
    _add_sphere(flange, "load", offset, load.mass * load.mass_scale)


def _add_sphere(flange: mujoco.MjsSite, name: str, offset: np.ndarray, mass: float) -> None:
    """A solid sphere of PAYLOAD_RADIUS and `mass` centred `offset` from the flange's centre."""
    inertia = 0.4 * mass * PAYLOAD_RADIUS**2
    flange.parent.add_body(
        name=name,
        pos=np.asarray(flange.pos) + offset,
        # The centre of mass on the body's origin: left unset, MuJoCo puts it at `pos` again.
        ipos=[0.0, 0.0, 0.0],
        mass=mass,
        inertia=[inertia] * 3,
    )


def _log_warning(message: str) -> None:
    log.debug("MuJoCo: %s", message)
