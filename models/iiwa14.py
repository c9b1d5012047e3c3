"""Build the simulated iiwa 14 from the one hand-written source, models/iiwa14.xml.

Both variants come from that file, so they never drift apart:
- rigid: each joint Ai is one hinge carrying the link, the rotor's reflected inertia its armature;
- flexible (Spong's elastic joint): each joint becomes two coaxial hinges in the link's body,
  Ai_motor (motor side θ, armature = rotor inertia B, driven by the motor) followed by Ai_spring
  (deflection q − θ, torsional stiffness K and damping D). The link angle is q = θ + (q − θ), the
  sum of the two. Putting both hinges in one body is the massless-rotor form of the model: the
  kinetic energy is ½ I q̇² + ½ B θ̇², exactly Spong's.
"""

import logging
from functools import lru_cache
from importlib.resources import files

import mujoco

from schemas.robot import JOINT_NAMES, ModelSpec
from schemas.trajectory import CONTROL_PERIOD

log = logging.getLogger("gainfarm.models")

RIGID_MJCF = files("models").joinpath("iiwa14.xml")
FLANGE = "flange"  # the site at the flange's centre: the end effector every trajectory moves


def build_spec(spec: ModelSpec) -> mujoco.MjSpec:
    """The MuJoCo model description for `spec`, not yet compiled (export it with .to_xml())."""
    mj = mujoco.MjSpec.from_string(RIGID_MJCF.read_text())
    mj.option.timestep = CONTROL_PERIOD / spec.substeps
    # A diverging episode must stay diverged (NaNs are data we detect), not be silently reset.
    mj.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    for i, name in enumerate(JOINT_NAMES):
        hinge = mj.joint(name)
        hinge.armature = spec.rotor_inertia[i]
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


@lru_cache(maxsize=16)
def compile_model(spec: ModelSpec) -> mujoco.MjModel:
    """Compiled model for `spec`; cached, because a worker runs thousands of episodes on one."""
    # An unstable simulation is data (the episode is flagged as diverged), not a warning for
    # stdout and a MUJOCO_LOG.TXT in whatever directory the process runs in: MuJoCo's default.
    # A handler the process installed itself is left in place.
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_log_warning)
    return build_spec(spec).compile()


def _log_warning(message: str) -> None:
    log.debug("MuJoCo: %s", message)
