"""Robot models: the arms of the gainfarm.robots plug-in group, and the lookup from a plant to
its robot (`robot_of`). The iiwa 14 (models/iiwa14.py: the rigid MJCF and the elastic-joint
variant generated from it) is the built-in one.

`compile_model`, `build_spec`, `resolve`, `min_substeps` and `plant_preset` are the named robot's;
the other names are the iiwa 14's (its postures, inertial sets and step analysis).
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
    step_ratios,
)
from gainfarm.models.robots import (
    PlantError,
    build_spec,
    compile_model,
    min_substeps,
    plant_preset,
    resolve,
    robot_of,
    written_out,
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
    "written_out",
]
