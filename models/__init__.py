"""Robot models: the rigid iiwa 14 MJCF and the elastic-joint variant generated from it."""

from models.iiwa14 import FLANGE, RIGID_MJCF, build_spec, compile_model

__all__ = ["FLANGE", "RIGID_MJCF", "build_spec", "compile_model"]
