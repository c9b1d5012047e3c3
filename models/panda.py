"""The Franka Emika Panda (7 joints) as a gainfarm.robots plug-in: MuJoCo Menagerie's model
(models/menagerie/panda/) built by models/mjcf_arm.py. Every number's source or assumption:
models/README.md, section "Franka Emika Panda"."""

import math
from importlib.resources import files

from gainfarm.models.mjcf_arm import MjcfArm
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import JointLimits, PlantDefaults, TorqueInterface, Workspace

JOINT_NAMES = tuple(f"panda_joint{i}" for i in range(1, 8))  # franka_description's names
# Franka Emika's robot and interface specifications (the FCI documentation, libfranka 0.9) and
# franka_description's joint_limits.yaml: the joint ranges (low, high), rad, speed, acceleration
# and torque limits.
POSITION_RANGES = (
    (-2.8973, 2.8973),
    (-1.7628, 1.7628),
    (-2.8973, 2.8973),
    (-3.0718, -0.0698),
    (-2.8973, 2.8973),
    (-0.0175, 3.7525),
    (-2.8973, 2.8973),
)
TORQUE_LIMITS = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
SPEED_LIMITS = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)
ACCELERATION_LIMITS = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)
# JointLimits holds symmetric ranges: each joint's widest excursion (the hinges get the ranges).
POSITION_LIMITS = tuple(max(-low, high) for low, high in POSITION_RANGES)
RATED_PAYLOAD = 3.0  # kg, Franka Emika's Panda data sheet

TORQUE_INTERFACE = TorqueInterface(
    name="libfranka torque control",
    adds_gravity=True,
    description="libfranka's torque control at 1 kHz (Franka Control Interface): the desired "
    "joint torques, which the robot adds to its own gravity and motor friction compensation "
    "(the command must not include gravity)",
)

# Assumptions (models/README.md, "Franka Emika Panda"): the iiwa 14's rules by torque class. Rotor
# inertia Menagerie's armature (0.1 kg·m² every joint); Coulomb friction 1.5 % of the torque
# limit; viscous friction and spring damping the iiwa's of the nearest torque class; the
# stiffness presets the iiwa's of that class, "medium" as stiff as substeps = 2 integrates well.
PLANT_DEFAULTS = PlantDefaults(
    stiffness_presets={
        "soft": (2000.0, 2000.0, 2000.0, 2000.0, 1000.0, 1000.0, 1000.0),
        "medium": (7000.0, 7000.0, 7000.0, 7000.0, 2000.0, 2000.0, 2000.0),
        "stiff": (20000.0, 20000.0, 20000.0, 20000.0, 10000.0, 10000.0, 10000.0),
    },
    stiffness="medium",
    spring_damping=(10.0, 10.0, 10.0, 10.0, 5.0, 5.0, 5.0),
    rotor_inertia=(0.1,) * 7,
    viscous=(0.3, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1),
    coulomb=tuple(round(0.015 * limit, 3) for limit in TORQUE_LIMITS),
)

# Kp: Franka's own, the joint stiffness of libfranka's joint_impedance_control example. Kd: the
# rule of the other arms, Kp / 100 s: the example's damping (50, 50, 50, 50, 30, 25, 15) makes
# joint 3 ring by 15 mrad on this plant (a command acting a tick late, velocities differenced
# from the encoders), where the kit allows 5.
DEFAULT_GAINS = PDGains(
    kp=(600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0),
    kd=(6.0, 6.0, 6.0, 6.0, 2.5, 1.5, 0.5),
)

# Home: the flange pointing down over the iiwa's default centre, joints 1, 3, 5 and 7 as in
# Franka's ready pose (0, -π/4, 0, -3π/4, 0, π/2, π/4); the iiwa's box of centres.
WORKSPACE = Workspace(
    home=(0.0, 0.10113, 0.0, -2.16327, 0.0, 2.2644, math.pi / 4),
    center=(0.55, 0.0, 0.35),
    low=(0.5, -0.15, 0.3),
    high=(0.65, 0.15, 0.45),
)

ROBOT = MjcfArm(
    name="panda",
    mjcf=files("gainfarm.models").joinpath("menagerie/panda/panda_nohand.xml"),
    joint_names=JOINT_NAMES,
    limits=JointLimits(
        torque=TORQUE_LIMITS,
        speed=SPEED_LIMITS,
        position=POSITION_LIMITS,
        acceleration=ACCELERATION_LIMITS,
    ),
    default_gains=DEFAULT_GAINS,
    workspace=WORKSPACE,
    torque_interface=TORQUE_INTERFACE,
    plant_defaults=PLANT_DEFAULTS,
    rated_payload=RATED_PAYLOAD,
    uncertainty=files("gainfarm.models").joinpath("uncertainty_panda.toml"),
    file_joints=tuple(f"joint{i}" for i in range(1, 8)),
    position_ranges=POSITION_RANGES,
    # franka_description's panda_link8, the flange: 0.107 m out along joint 7's axis, z outwards;
    # turned as Menagerie's attachment site (the hand's mount), 135° about it, so that joint 7
    # at the middle of its range (π/4, the ready pose's) holds the tool as the trajectories do.
    flange_pos=(0.0, 0.0, 0.107),
    flange_quat=(0.3826834, 0.0, 0.0, 0.9238795),
)
