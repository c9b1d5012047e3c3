"""The Kinova Gen3 (7 joints) as a gainfarm.robots plug-in: MuJoCo Menagerie's model
(models/menagerie/gen3/) built by models/mjcf_arm.py. Every number's source or assumption:
models/README.md, section "Kinova Gen3"."""

import math
from importlib.resources import files

from gainfarm.models.mjcf_arm import MjcfArm
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import JointLimits, PlantDefaults, TorqueInterface, Workspace

JOINT_NAMES = tuple(f"joint_{i}" for i in range(1, 8))  # ros2_kortex's names, Menagerie's too
# ros2_kortex's gen3 description: 39 N·m and 1.3963 rad/s on the large actuators (joints 1-4),
# 9 N·m and 1.2218 rad/s on the small ones (5-7); its hard joint limits for MoveIt: 4.94 and
# 9.5 rad/s². Positions: Kinova's Gen3 user guide, ±128.9°, ±147.8°, ±120.3° on joints 2, 4, 6;
# joints 1, 3, 5, 7 turn without end, held here to ±2π (assumption: a hinge needs a range).
TORQUE_LIMITS = (39.0, 39.0, 39.0, 39.0, 9.0, 9.0, 9.0)
SPEED_LIMITS = (1.3963, 1.3963, 1.3963, 1.3963, 1.2218, 1.2218, 1.2218)
ENDLESS = 2 * math.pi
POSITION_LIMITS = (
    ENDLESS,
    math.radians(128.9),
    ENDLESS,
    math.radians(147.8),
    ENDLESS,
    math.radians(120.3),
    ENDLESS,
)
ACCELERATION_LIMITS = (4.94, 4.94, 4.94, 4.94, 9.5, 9.5, 9.5)
RATED_PAYLOAD = 4.0  # kg, Kinova's Gen3 specifications (mid-range, continuous)

TORQUE_INTERFACE = TorqueInterface(
    name="Kinova Kortex low-level torque control",
    adds_gravity=False,
    description="Kortex API low-level servoing at 1 kHz with the actuators in torque mode: "
    "each command goes to the actuators as it is, bypassing the base's control loop, so the "
    "commanded joint torque must itself hold the arm against gravity",
)

# Assumptions (models/README.md, "Kinova Gen3"): the iiwa 14's rules by torque class. Rotor
# inertia the iiwa's per N·m of torque (0.1 kg·m² at 40 N·m); Coulomb friction 1.5 % of the
# torque limit; viscous friction and spring damping the iiwa's of its smallest class; the
# stiffness presets the iiwa's 40 N·m class, "medium" as stiff as substeps = 2 integrates well.
PLANT_DEFAULTS = PlantDefaults(
    stiffness_presets={
        "soft": (2000.0, 2000.0, 2000.0, 2000.0, 1000.0, 1000.0, 1000.0),
        "medium": (7000.0, 7000.0, 5000.0, 7000.0, 2000.0, 2000.0, 2000.0),
        "stiff": (20000.0, 20000.0, 20000.0, 20000.0, 10000.0, 10000.0, 10000.0),
    },
    stiffness="medium",
    spring_damping=(5.0,) * 7,
    rotor_inertia=(0.1, 0.1, 0.1, 0.1, 0.025, 0.025, 0.025),
    viscous=(0.1,) * 7,
    coulomb=tuple(round(0.015 * limit, 3) for limit in TORQUE_LIMITS),
)

# Rule (the iiwa 14's A1): full torque at an error of 0.15 rad, Kp = τ_max / 0.15; Kd = Kp / 100.
DEFAULT_GAINS = PDGains(
    kp=tuple(round(limit / 0.15) for limit in TORQUE_LIMITS),
    kd=tuple(round(limit / 15, 2) for limit in TORQUE_LIMITS),
)

# Home: the flange pointing down over the iiwa's default centre, joints 1, 3, 5 as in Menagerie's
# home (the arm in the x-z plane); the box of centres is the one whose corners the kit reaches.
WORKSPACE = Workspace(
    home=(0.0, 0.64556, math.pi, -1.26055, 0.0, -1.23549, math.pi),
    center=(0.55, 0.0, 0.35),
    low=(0.45, -0.1, 0.3),
    high=(0.55, 0.1, 0.4),
)

ROBOT = MjcfArm(
    name="gen3",
    mjcf=files("gainfarm.models").joinpath("menagerie/gen3/gen3.xml"),
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
    uncertainty=files("gainfarm.models").joinpath("uncertainty_gen3.toml"),
    # ros2_kortex's end_effector_link (Menagerie's pinch_site): 61.5 mm out along joint 7's
    # axis, z outwards.
    flange_pos=(0.0, 0.0, -0.061525),
    flange_quat=(0.0, 1.0, 0.0, 0.0),
)
