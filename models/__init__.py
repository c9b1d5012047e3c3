"""Robot models: the rigid iiwa 14 MJCF and the elastic-joint variant generated from it."""

from gainfarm.models.iiwa14 import (
    CAD_INERTIALS,
    FLANGE,
    MAX_STEP_RATIO,
    READY_POSTURE,
    RIGID_MJCF,
    UPRIGHT_POSTURE,
    build_spec,
    check_substeps,
    compile_model,
    effective_inertias,
    elastic_modes,
    min_substeps,
    step_ratios,
)

__all__ = [
    "CAD_INERTIALS",
    "FLANGE",
    "MAX_STEP_RATIO",
    "READY_POSTURE",
    "RIGID_MJCF",
    "UPRIGHT_POSTURE",
    "build_spec",
    "check_substeps",
    "compile_model",
    "effective_inertias",
    "elastic_modes",
    "min_substeps",
    "step_ratios",
]
