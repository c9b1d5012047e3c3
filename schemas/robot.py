"""The robot model a job runs on: which variant and its (assumed) elastic-joint parameters."""

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

N_JOINTS = 7
JOINT_NAMES = tuple(f"A{i}" for i in range(1, N_JOINTS + 1))

# Data-sheet torque limits of the LBR iiwa 14 R820, N·m; the motors' ctrlrange in models/iiwa14.xml.
TORQUE_LIMITS = (320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)

# Elastic-joint parameters. No authoritative public table exists: these are documented assumptions
# in the orders of magnitude the reference gives (models/README.md explains the choice).
DEFAULT_STIFFNESS = (5000.0, 5000.0, 4000.0, 4000.0, 2000.0, 2000.0, 2000.0)  # N·m/rad
DEFAULT_SPRING_DAMPING = (10.0, 10.0, 10.0, 10.0, 5.0, 5.0, 5.0)  # N·m·s/rad
DEFAULT_ROTOR_INERTIA = (0.4, 0.4, 0.3, 0.3, 0.1, 0.1, 0.1)  # kg·m², reflected through the gear

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
PerJointPositive = Annotated[
    tuple[PositiveFloat, ...], Field(min_length=N_JOINTS, max_length=N_JOINTS)
]
PerJointNonNegative = Annotated[
    tuple[NonNegativeFloat, ...], Field(min_length=N_JOINTS, max_length=N_JOINTS)
]


class ModelSpec(BaseModel):
    """Which simulated robot runs an episode. Values are explicit so that logs record them."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    robot: Literal["iiwa14"] = "iiwa14"
    joints: Literal["flexible", "rigid"] = "flexible"
    stiffness: PerJointPositive = DEFAULT_STIFFNESS
    spring_damping: PerJointNonNegative = DEFAULT_SPRING_DAMPING
    rotor_inertia: PerJointNonNegative = DEFAULT_ROTOR_INERTIA
    substeps: int = Field(2, ge=1, le=50, description="physics steps per 2 ms control tick")
