"""Build the simulated iiwa 14 from the one hand-written source, models/iiwa14.xml.

Both variants come from that file, so they never drift apart:
- rigid: each joint Ai is one hinge carrying the link, the rotor's reflected inertia its armature;
- flexible (Spong's elastic joint): each joint becomes two coaxial hinges in the link's body,
  Ai_motor (motor side θ, armature = rotor inertia B, driven by the motor) followed by Ai_spring
  (deflection q − θ, torsional stiffness K and damping D). The link angle is q = θ + (q − θ), the
  sum of the two. Putting both hinges in one body is the massless-rotor form of the model: the
  kinetic energy is ½ I q̇² + ½ B θ̇², exactly Spong's.

The XML holds the "open" inertial set; `MENAGERIE_AXES` below turns it into the "menagerie" one (the
default) and `CAD_INERTIALS` into the "cad" one. Viscous
friction, when the spec has friction, is the motor hinge's damping. `compile_model` refuses a spec
whose joint springs MuJoCo cannot integrate stably and accurately at its physics step
(`check_substeps`). Sources and assumptions for every number: models/README.md.

`ROBOT` is the iiwa 14 as the gainfarm.robots plug-in group declares an arm (schemas.robot.Robot):
its limits, default gains, gravity model and workspace; the built-in robot, and the default.
"""

import logging
from functools import lru_cache
from importlib.resources import files

import mujoco
import numpy as np

from gainfarm.models import elastic
from gainfarm.models.robots import resolve
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.robot import (
    ACCELERATION_LIMITS,
    DEFAULT_ROTOR_INERTIA,
    DEFAULT_SPRING_DAMPING,
    JOINT_NAMES,
    POSITION_LIMITS,
    RATED_PAYLOAD,
    SPEED_LIMITS,
    STIFFNESS_PRESETS,
    TORQUE_LIMITS,
    JointLimits,
    LoadData,
    PlantDefaults,
    PlantSpec,
    TorqueInterface,
    Workspace,
)
from gainfarm.schemas.trajectory import CONTROL_PERIOD

log = logging.getLogger("gainfarm.models")

RIGID_MJCF = files("gainfarm.models").joinpath("iiwa14.xml")
FLANGE = "flange"  # the site at the flange's centre: the end effector every trajectory moves

# The "cad" inertial set, as changes to the "open" one in models/iiwa14.xml. Per link: mass in kg
# (KUKA's CAD masses as noted in drake's iiwa 14 URDF), and where MuJoCo Menagerie's kuka_iiwa_14
# re-orients the principal axes, their orientation (w x y z, Menagerie's inertial quat). Centres
# of mass stay the open ones, and the principal inertias are the open ones scaled by the mass
# ratio (same radii of gyration): both assumptions, as no CAD values for them are published.
CAD_INERTIALS: dict[str, tuple[float, tuple[float, float, float, float] | None]] = {
    "link1": (4.0, None),  # assumption: no CAD mass is published; iiwa_stack's value
    "link2": (3.95, (0.0, 0.0, 1.0, 1.0)),
    "link3": (3.18, None),
    "link4": (2.74, (1.0, 1.0, 0.0, 0.0)),
    "link5": (1.69, None),
    "link6": (1.8, (1.0, 1.0, 0.0, 0.0)),
    "link7": (0.31, None),
}

# Postures at which the springs' modes are analysed: the ready posture, and the arm stretched
# upright, where the roll joints A1, A3, A5 and A7 turn the least inertia (their fastest modes).
READY_POSTURE = (0.0, 0.5, 0.0, -1.6, 0.0, 1.0, 0.0)
UPRIGHT_POSTURE = (0.0,) * 7

# The largest step ratio K dt² / (4 m + 2 D dt) a spring may have (models/elastic.py says why).
MAX_STEP_RATIO = elastic.MAX_STEP_RATIO


# The "menagerie" inertial set (the default): the open set's masses and centres of mass (30.6 kg
# with the base, the data sheet's 29.9 kg within 2.4 %) with the principal axes MuJoCo Menagerie's
# kuka_iiwa_14 gives links 2, 4 and 6 (its inertial quats): the set Menagerie ships today.
MENAGERIE_AXES = {
    body: orientation for body, (_, orientation) in CAD_INERTIALS.items() if orientation is not None
}


# Motor-side viscous friction, N·m·s/rad (assumption: models/README.md).
VISCOUS_FRICTION = (0.5, 0.5, 0.3, 0.3, 0.2, 0.1, 0.1)

PAYLOAD_RADIUS = 0.05  # m: a payload is a solid sphere this big at the flange (assumption)


def build_spec(spec: PlantSpec) -> mujoco.MjSpec:
    """The MuJoCo model description for `spec`, not yet compiled (export it with .to_xml())."""
    spec = resolve(spec)
    mj = mujoco.MjSpec.from_string(RIGID_MJCF.read_text())
    mj.option.timestep = CONTROL_PERIOD / spec.substeps
    # A diverging episode must stay diverged (NaNs are data we detect), not be silently reset.
    mj.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    if spec.inertials == "cad":
        for body, (mass, orientation) in CAD_INERTIALS.items():
            link = mj.body(body)
            link.inertia = link.inertia * (mass / link.mass)
            link.mass = mass
            if orientation is not None:
                link.iquat = orientation
    elif spec.inertials == "menagerie":
        for body, orientation in MENAGERIE_AXES.items():
            mj.body(body).iquat = orientation
    for i, scale in enumerate(spec.mass_scale):
        if scale != 1.0:  # the true link, heavier or lighter than its set says, its shape kept
            link = mj.body(f"link{i + 1}")
            link.mass = link.mass * scale
            link.inertia = link.inertia * scale
    if spec.payload > 0:
        # A solid sphere of PAYLOAD_RADIUS centred on the flange (assumption: a compact load).
        flange = next(site for site in mj.sites if site.name == FLANGE)
        inertia = 0.4 * spec.payload * PAYLOAD_RADIUS**2
        mj.body("link7").add_body(
            name="payload",
            pos=flange.pos,
            ipos=[0.0, 0.0, 0.0],  # on the flange's centre, not as far out again (as the load)
            mass=spec.payload,
            inertia=[inertia] * 3,
        )
    if spec.load is not None:
        _add_load(mj, spec.load)
    for i, name in enumerate(JOINT_NAMES):
        hinge = mj.joint(name)
        hinge.armature = spec.rotor_inertia[i]
        if spec.friction is not None:
            # Viscous friction on the motor side. MuJoCo integrates joint damping implicitly: it
            # costs nothing and is stable at any step. The Coulomb part is the tick loop's.
            damping = np.array(hinge.damping)  # MuJoCo 4: (linear, polynomial terms...)
            damping[0] = spec.friction.viscous[i]
            hinge.damping = damping
        if spec.joints == "flexible":
            hinge.name = f"{name}_motor"
            mj.actuator(name).target = hinge.name
            mj.body(f"link{i + 1}").add_joint(
                name=f"{name}_spring",
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=[0, 0, 1],
                stiffness=spec.stiffness[i],
                damping=spec.spring_damping[i],
                limited=mujoco.mjtLimited.mjLIMITED_FALSE,
            )
    return mj


def _add_load(mj: mujoco.MjSpec, load: LoadData) -> None:
    """The load, a solid sphere of PAYLOAD_RADIUS (assumption, as the payload's) centred on its
    centre of mass, given in the flange frame: of its true mass (the plant's, or, `load.told`,
    the robot's own model's: gravity reads only its mass and centre)."""
    flange = next(site for site in mj.sites if site.name == FLANGE)
    offset = np.zeros(3)
    mujoco.mju_rotVecQuat(offset, np.asarray(load.com, dtype=float), np.asarray(flange.quat))
    mass = load.mass * load.mass_scale
    inertia = 0.4 * mass * PAYLOAD_RADIUS**2
    mj.body("link7").add_body(
        name="load",
        pos=np.asarray(flange.pos) + offset,
        # The centre of mass on the body's origin: left unset, MuJoCo puts it at `pos` again,
        # twice as far out.
        ipos=[0.0, 0.0, 0.0],
        mass=mass,
        inertia=[inertia] * 3,
    )


@lru_cache(maxsize=16)
def compile_model(spec: PlantSpec) -> mujoco.MjModel:
    """Compiled model for `spec`; cached, because a worker runs thousands of episodes on one.

    Raises ValueError if the spec's physics step is too long for its joint springs."""
    # An unstable simulation is data (the episode is flagged as diverged), not a warning for
    # stdout and a MUJOCO_LOG.TXT in whatever directory the process runs in: MuJoCo's default.
    # A handler the process installed itself is left in place.
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_log_warning)
    model = build_spec(spec).compile()
    check_substeps(spec, model)
    return model


def check_substeps(spec: PlantSpec, model: mujoco.MjModel | None = None) -> None:
    """Raise ValueError, in one line, if `spec.substeps` is too few for its joint springs."""
    if spec.joints != "flexible":
        return
    spec = resolve(spec)
    inertia = effective_inertias(spec, model)
    elastic.check_substeps(spec.substeps, spec.stiffness, spec.spring_damping, inertia, JOINT_NAMES)


def min_substeps(spec: PlantSpec, model: mujoco.MjModel | None = None) -> int:
    """The fewest physics steps per control tick that integrate `spec`'s joint springs well
    (every joint's step ratio at most MAX_STEP_RATIO); 1 for rigid joints."""
    if spec.joints != "flexible":
        return 1
    spec = resolve(spec)
    inertia = effective_inertias(spec, model)
    return elastic.min_substeps(spec.stiffness, spec.spring_damping, inertia, JOINT_NAMES)


def step_ratios(spec: PlantSpec, model: mujoco.MjModel | None = None) -> np.ndarray:
    """Per joint, K dt² / (4 m + 2 D dt) at `spec`'s physics step dt: MuJoCo's integration of the
    joint's spring is stable below 1; `compile_model` wants every one at most MAX_STEP_RATIO.
    m is the spring's effective inertia (`effective_inertias`)."""
    spec = resolve(spec)
    inertia = effective_inertias(spec, model)
    dt = CONTROL_PERIOD / spec.substeps
    return elastic.step_ratios(spec.stiffness, spec.spring_damping, inertia, dt)


def effective_inertias(spec: PlantSpec, model: mujoco.MjModel | None = None) -> np.ndarray:
    """Per joint, the inertia its spring turns, kg·m²: the link side's against the rotor's,
    I B / (I + B), from the mass matrix with every other joint held; the smaller of its values
    at READY_POSTURE and UPRIGHT_POSTURE. `model` is `spec`'s compiled flexible model, if at hand.
    """
    if model is None:
        model = build_spec(spec.model_copy(update={"joints": "flexible"})).compile()
    return elastic.effective_inertias(model, JOINT_NAMES, (READY_POSTURE, UPRIGHT_POSTURE))


def elastic_modes(spec: PlantSpec, posture: tuple[float, ...] = READY_POSTURE) -> np.ndarray:
    """The 7 undamped elastic modes of `spec`'s flexible plant linearised at `posture`, Hz,
    ascending: the generalized eigenproblem of the spring stiffness against the mass matrix."""
    model = build_spec(spec.model_copy(update={"joints": "flexible"})).compile()
    data = mujoco.MjData(model)
    motor = model.jnt_qposadr[model.actuator_trnid[:, 0]]
    data.qpos[motor] = posture
    mujoco.mj_forward(model, data)
    mass_matrix = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, mass_matrix)
    stiffness = np.diag(model.jnt_stiffness[model.dof_jntid])
    cholesky_inverse = np.linalg.inv(np.linalg.cholesky(mass_matrix))
    omega_squared = np.linalg.eigvalsh(cholesky_inverse @ stiffness @ cholesky_inverse.T)
    # The 7 zero eigenvalues are the rigid motions (motor and link turning together).
    return np.sqrt(np.clip(omega_squared[-len(JOINT_NAMES) :], 0.0, None)) / (2 * np.pi)


def _log_warning(message: str) -> None:
    log.debug("MuJoCo: %s", message)


def gravity_spec(spec: PlantSpec) -> PlantSpec:
    """The rigid arm whose gravity the robot's model of `spec` computes, as KUKA's controller
    adds it in FRI torque mode: its inertial set and the load it is told (KUKA's load data), no
    more (rotor inertia, springs and friction exert no gravity torque; the untold payload and the
    links' and load's true masses it never knows)."""
    return PlantSpec(
        robot=spec.robot,
        joints="rigid",
        inertials=spec.inertials,
        friction=None,
        substeps=1,
        interface="torque",
        load=None if spec.load is None else spec.load.told,
    )


# The ready posture (the flange pointing down over the default centre) is the one the inverse
# kinematics starts from. The box of trajectory centres: x 0.5-0.65 m, y ±0.15 m, z 0.3-0.45 m,
# around the default centre (0.55, 0, 0.35) m, where a default 8 cm spiral around any point is
# reached with the tool pointing down from the ready posture (gainfarm.testing.robots checks its
# corners); nearer the base and lower, A4 runs out of range (at x 0.45, z 0.25: by 2-6 mm).
WORKSPACE = Workspace(
    home=READY_POSTURE,
    center=(0.55, 0.0, 0.35),
    low=(0.5, -0.15, 0.3),
    high=(0.65, 0.15, 0.45),
)


class Iiwa14:
    """The KUKA LBR iiwa 14 R820 (schemas.robot.Robot): the data sheet's limits, the default
    gains, the MJCF of models/iiwa14.xml with rigid or elastic joints, FRI's gravity model."""

    name = "iiwa14"
    joint_names = JOINT_NAMES
    limits = JointLimits(
        torque=TORQUE_LIMITS,
        speed=SPEED_LIMITS,
        position=POSITION_LIMITS,
        acceleration=ACCELERATION_LIMITS,
    )
    default_gains: PDGains = DEFAULT_GAINS
    workspace = WORKSPACE
    flange = FLANGE
    plant_defaults = PlantDefaults(
        stiffness_presets=STIFFNESS_PRESETS,
        stiffness="medium",  # the stiffest 1 ms physics steps integrate well
        spring_damping=DEFAULT_SPRING_DAMPING,
        rotor_inertia=DEFAULT_ROTOR_INERTIA,
        viscous=VISCOUS_FRICTION,
        coulomb=tuple(round(0.015 * limit, 3) for limit in TORQUE_LIMITS),
    )
    torque_interface = TorqueInterface(
        name="KUKA FRI torque mode",
        adds_gravity=True,
        description="the robot adds the torque holding the measured joint angles against "
        "gravity, from its own model of the arm and the load data it is told, to the command; "
        "the motors exert the sum (KUKA Sunrise.FRI 1.x manual)",
    )
    inertial_sets = ("menagerie", "open", "cad")
    rated_payload = RATED_PAYLOAD
    uncertainty = files("gainfarm.models").joinpath("uncertainty.toml")

    def build(self, spec: PlantSpec) -> mujoco.MjModel:
        return compile_model(spec)

    def describe(self, spec: PlantSpec) -> mujoco.MjSpec:
        return build_spec(spec)

    def gravity_spec(self, spec: PlantSpec) -> PlantSpec:
        return gravity_spec(spec)

    def min_substeps(self, spec: PlantSpec) -> int:
        # As every MjcfArm has: the fewest physics steps per tick its springs need.
        return min_substeps(spec)

    def __repr__(self) -> str:
        return "<robot iiwa14>"


ROBOT = Iiwa14()
