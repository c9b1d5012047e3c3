"""The Universal Robots UR5e (6 joints) as a gainfarm.robots plug-in: MuJoCo Menagerie's model
(models/menagerie/ur5e/) built by models/mjcf_arm.py. Every number's source or assumption:
models/README.md, section "UR5e"."""

import math
from importlib.resources import files

from gainfarm.models.mjcf_arm import MjcfArm
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import (
    JointLimits,
    PlantDefaults,
    TorqueInterface,
    Workspace,
)

JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
# Universal Robots' "Max. joint torques" (size 3 joints 150 N·m, size 1 28 N·m) and
# ur_description's ur5e joint_limits.yaml (the same; 180 °/s every joint; ±2π, the elbow ±π).
TORQUE_LIMITS = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
SPEED_LIMITS = (math.pi,) * 6
POSITION_LIMITS = (2 * math.pi, 2 * math.pi, math.pi, 2 * math.pi, 2 * math.pi, 2 * math.pi)
# Assumption: UR publishes no acceleration limit (its MoveIt configuration says the robot has
# torque limits only, and takes 5 rad/s² for planning, conservatively); the iiwa 14's, 8.6 to
# 15.7 rad/s², are of the same class of arm: 10 on the size 3 joints, 15 on the wrists.
ACCELERATION_LIMITS = (10.0, 10.0, 10.0, 15.0, 15.0, 15.0)
RATED_PAYLOAD = 5.0  # kg, UR5e data sheet

TORQUE_INTERFACE = TorqueInterface(
    name="UR direct torque control",
    adds_gravity=True,
    description="URScript direct_torque (PolyScope 5.23 and later, 500 Hz): the joint torques "
    "commanded each 2 ms; the controller always adds its own gravity compensation (the "
    "command must not include it) and, scaled per joint, its friction model's compensation",
)

# Assumptions (models/README.md, "UR5e"): the iiwa 14's rules by torque class. Rotor inertia is
# Menagerie's armature (0.1 kg·m² every joint); Coulomb friction 1.5 % of the torque limit;
# viscous friction and spring damping the iiwa's of the nearest torque class; the stiffness
# presets the iiwa's by torque class, each "medium" as stiff as substeps = 2 integrates well.
PLANT_DEFAULTS = PlantDefaults(
    stiffness_presets={
        "soft": (4000.0, 4000.0, 4000.0, 2000.0, 2000.0, 1000.0),
        "medium": (20000.0, 20000.0, 20000.0, 7000.0, 5000.0, 2000.0),
        "stiff": (50000.0, 50000.0, 50000.0, 20000.0, 20000.0, 10000.0),
    },
    stiffness="medium",
    spring_damping=(10.0, 10.0, 10.0, 5.0, 5.0, 5.0),
    rotor_inertia=(0.1,) * 6,
    viscous=(0.3, 0.3, 0.3, 0.1, 0.1, 0.1),
    coulomb=tuple(round(0.015 * limit, 3) for limit in TORQUE_LIMITS),
)

# Rule (the iiwa 14's A1): full torque at an error of 0.15 rad, Kp = τ_max / 0.15; Kd = Kp / 100.
DEFAULT_GAINS = PDGains(
    kp=tuple(round(limit / 0.15) for limit in TORQUE_LIMITS),
    kd=tuple(round(limit / 15, 2) for limit in TORQUE_LIMITS),
)

# Menagerie's home (the tool pointing down, the arm over +x); the iiwa 14's default centre and
# box of centres, every corner reached (the kit checks).
WORKSPACE = Workspace(
    home=(-math.pi / 2, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0),
    center=(0.55, 0.0, 0.35),
    low=(0.5, -0.15, 0.3),
    high=(0.65, 0.15, 0.45),
)

ROBOT = MjcfArm(
    name="ur5e",
    mjcf=files("gainfarm.models").joinpath("menagerie/ur5e/ur5e.xml"),
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
    uncertainty=files("gainfarm.models").joinpath("uncertainty_ur5e.toml"),
    # ur_description's tool0: 0.1 m out along wrist 3's axis (Menagerie's y), z outwards, x
    # turned so that at home the flange is exactly the trajectories' tool-down orientation.
    flange_pos=(0.0, 0.1, 0.0),
    flange_quat=(0.5, -0.5, 0.5, 0.5),
)
