"""Robot models: the arms of the gainfarm.robots plug-in group, and the lookup from a plant to
its robot (`robot_of`). The iiwa 14 (models/iiwa14.py: the rigid MJCF and the elastic-joint
variant generated from it) is the built-in one.

`compile_model` and `build_spec` build the robot the plant names; the other names are the iiwa
14's, kept here for the code that still assumes its 7 joints (docs/robot.md).
"""

from gainfarm.models.iiwa14 import (
    CAD_INERTIALS,
    FLANGE,
    MAX_STEP_RATIO,
    READY_POSTURE,
    RIGID_MJCF,
    UPRIGHT_POSTURE,
    check_substeps,
    effective_inertias,
    elastic_modes,
    min_substeps,
    step_ratios,
)
from gainfarm.models.robots import (
    PlantError,
    build_spec,
    compile_model,
    plant_preset,
    resolve,
    robot_of,
)

__all__ = [
    "CAD_INERTIALS",
    "FLANGE",
    "MAX_STEP_RATIO",
    "READY_POSTURE",
    "RIGID_MJCF",
    "UPRIGHT_POSTURE",
    "PlantError",
    "build_spec",
    "check_substeps",
    "compile_model",
    "effective_inertias",
    "elastic_modes",
    "min_substeps",
    "plant_preset",
    "resolve",
    "robot_of",
    "step_ratios",
]
