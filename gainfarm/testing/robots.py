"""The conformance kit for a robot plug-in (gainfarm.robots): the checks an arm's author runs.

Each check takes the plug-in's ROBOT (schemas.robot.Robot) and raises AssertionError, saying what
is wrong, if it does not conform; they run the real thing (MuJoCo, the worker's tick loop and
inverse kinematics). With pytest, subclass `RobotChecks` and give it a `robot` fixture:

    import pytest
    from gainfarm.testing.robots import RobotChecks
    from mypkg.arm import ROBOT

    class TestMyArm(RobotChecks):
        @pytest.fixture
        def robot(self):
            return ROBOT

or call `check_robot(ROBOT)` for all of them. A robot not installed (no entry point yet) is
registered in-process for the checks that build it by its name, then forgotten.
"""

import math
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import mujoco
import numpy as np

from gainfarm import plugins
from gainfarm.analytic.tuning.plants import BadUncertainty, ranges
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.robot import (
    REALISTIC_PLANT,
    STIFFNESS_PRESET_NAMES,
    PlantSpec,
    Robot,
    TorqueInterface,
)
from gainfarm.schemas.trajectory import (
    CONTROL_PERIOD,
    MAX_DURATION,
    TrajectoryKind,
    TrajectorySpec,
)
from gainfarm.worker.episode import simulate
from gainfarm.worker.ik import UnreachablePath, solve_path
from gainfarm.worker.plant import Plant, RobotGravity
from gainfarm.worker.reference import (
    DEFAULT_SHARE,
    InfeasibleReference,
    Reference,
    arm_of,
    default_duration,
    forget_robots,
    reference_for,
)
from gainfarm.worker.trajectories import path_points, tool_rotations

# Holding still: an episode this long on the realistic plant (behind the robot's own gravity
# compensation, as the default gains are meant for), the reference standing at home; the arm
# starts NUDGE off home on every joint, so gains that do not act fail too (the robot's gravity
# model alone holds an arm wherever it is). Over the episode's second half the link angles may
# stray from home at most HOLD_TOLERANCE: the iiwa 14's default gains stay within 1.3 mrad; a
# tenth of its Kp leaves 13 mrad, no gains 20, twenty times its Kd makes A2 ring by 0.3 rad.
HOLD_SECONDS = 1.0
NUDGE = 0.02  # rad
HOLD_TOLERANCE = 0.005  # rad
# The robot's gravity model against MuJoCo's gravity torques on the rigid nominal plant: the same
# arm, so equal but for rounding.
GRAVITY_TOLERANCE = 1e-6  # N·m, plus the same relative to the torque
GRAVITY_POSTURES = 5  # seeded postures within each joint's range, besides home and zero
PATH_SAMPLES = 60  # inverse-kinematics samples along each workspace point's path


def check_name(robot: Robot) -> None:
    """The name is a plug-in name (gainfarm.plugins.NAME_PATTERN) and the object a Robot."""
    assert isinstance(robot, Robot), f"{robot!r} lacks a member of schemas.robot.Robot"
    assert isinstance(robot.name, str) and re.fullmatch(plugins.NAME_PATTERN, robot.name), (
        f"robot name {robot.name!r}: {plugins.NAME_RULE}"
    )


def check_limits(robot: Robot) -> None:
    """Every limit positive and finite, one per joint; default gains and home one per joint;
    home within the position limits."""
    joints = len(robot.joint_names)
    assert joints >= 1 and len(set(robot.joint_names)) == joints, "joint names: distinct, some"
    for which in ("torque", "speed", "position", "acceleration"):
        values = getattr(robot.limits, which)
        assert len(values) == joints, f"{which} limits: {len(values)} for {joints} joints"
        assert all(math.isfinite(v) and v > 0 for v in values), f"{which} limits: {values}"
    for which in ("kp", "kd"):
        gains = getattr(robot.default_gains, which)
        assert len(gains) == joints, f"default {which}: {len(gains)} gains for {joints} joints"
    home = robot.workspace.home
    assert len(home) == joints, f"workspace home: {len(home)} angles for {joints} joints"
    outside = [
        name
        for name, angle, limit in zip(robot.joint_names, home, robot.limits.position, strict=True)
        if abs(angle) > limit
    ]
    assert not outside, f"workspace home: {', '.join(outside)} beyond the position limit"


def check_members(robot: Robot) -> None:
    """What a plant and a farm read of the robot besides its limits: its plant defaults one
    number per joint (each stiffness preset too, the default one of them), non-negative, the
    rotors' inertia positive; its torque interface said; its inertial sets named, each building
    the arm; a positive, finite rated payload; its uncertainty ranges file parsing as
    models/uncertainty.toml's form."""
    joints = len(robot.joint_names)
    defaults = robot.plant_defaults
    presets = dict(defaults.stiffness_presets)
    assert set(presets) <= set(STIFFNESS_PRESET_NAMES), (
        f"stiffness presets {sorted(presets)}: only {', '.join(STIFFNESS_PRESET_NAMES)}"
    )
    assert defaults.stiffness in presets, f"default stiffness {defaults.stiffness!r}: no preset"
    per_joint = {f"stiffness preset {name}": values for name, values in presets.items()}
    per_joint |= {
        name: getattr(defaults, name)
        for name in ("spring_damping", "rotor_inertia", "viscous", "coulomb")
    }
    for name, values in per_joint.items():
        assert len(values) == joints, f"plant defaults' {name}: {len(values)} for {joints} joints"
        assert all(math.isfinite(v) and v >= 0 for v in values), f"{name}: {values}"
    assert min(defaults.rotor_inertia) > 0, "rotor_inertia: an elastic joint's rotor needs one"
    interface = robot.torque_interface
    assert isinstance(interface, TorqueInterface), f"torque_interface: {interface!r}"
    assert interface.name.strip() and interface.description.strip(), "torque_interface: unsaid"
    assert isinstance(interface.adds_gravity, bool), "torque_interface.adds_gravity: a bool"
    sets = robot.inertial_sets
    assert sets and all(re.fullmatch(plugins.NAME_PATTERN, name) for name in sets), (
        f"inertial_sets {sets!r}: one at least, each {plugins.NAME_RULE}"
    )
    payload = robot.rated_payload
    assert math.isfinite(payload) and payload > 0, f"rated_payload {payload!r}: positive, finite"
    try:
        ranges(robot.uncertainty.read_text())
    except (OSError, BadUncertainty) as error:
        raise AssertionError(f"uncertainty {robot.uncertainty}: {error}") from None
    with findable(robot):
        for name in sets:
            robot.build(nominal(robot, joints="rigid").model_copy(update={"inertials": name}))


def check_builds(robot: Robot) -> None:
    """The model builds for rigid and flexible joints; each has one motor per joint, the
    declared torque limits as the motors' range and the position limits as their hinges'; the
    plant reads every joint's angle from it; the flange site is there."""
    joints = len(robot.joint_names)
    with findable(robot):
        for kind in ("rigid", "flexible"):
            spec = nominal(robot, joints=kind)
            model = robot.build(spec)
            assert isinstance(model, mujoco.MjModel), f"{kind}: build gave {type(model)}"
            assert model.nu == joints, f"{kind}: {model.nu} motors for {joints} joints"
            plant = Plant(spec)
            assert plant.link_map.shape == (joints, model.nq), f"{kind}: joints and hinges"
            assert (plant.link_map.sum(axis=1) >= 1).all(), f"{kind}: a joint without a hinge"
            if kind == "rigid":
                assert model.nq == joints, f"rigid: {model.nq} hinges for {joints} joints"
            np.testing.assert_allclose(
                plant.torque_limits, robot.limits.torque, err_msg=f"{kind}: motors' ctrlrange"
            )
            np.testing.assert_allclose(
                plant.joint_range[:, 1], robot.limits.position, err_msg=f"{kind}: hinges' range"
            )
            model.site(robot.flange)  # KeyError if the flange is missing


def check_holds_still(robot: Robot) -> None:
    """The default gains hold the arm at home: a real episode on the realistic plant, rigid and
    flexible joints, its reference standing at home, the arm nudged off it at the start, is back
    within HOLD_TOLERANCE over the episode's second half, and does not diverge."""
    with findable(robot):
        for kind in ("rigid", "flexible"):
            spec = EpisodeSpec(
                gains=robot.default_gains,
                trajectory=TrajectorySpec(kind="fourier", duration=HOLD_SECONDS),
                plant=REALISTIC_PLANT.model_copy(update={"robot": robot.name, "joints": kind}),
            )
            log = simulate(spec, standing(robot, spec), None)
            assert not log.metadata.diverged, f"{kind}: diverged ({log.metadata.divergence})"
            assert log.metadata.ticks_run == log.metadata.ticks_planned, f"{kind}: cut short"
            settled = log.q[len(log.q) // 2 :]
            stray = np.abs(settled - np.asarray(robot.workspace.home)).max(axis=0)
            worst = int(stray.argmax())
            assert stray[worst] <= HOLD_TOLERANCE, (
                f"{kind}: {robot.joint_names[worst]} strays {stray[worst]:.3g} rad from home "
                f"(at most {HOLD_TOLERANCE} rad) under the default gains"
            )


def check_gravity(robot: Robot) -> None:
    """The robot's gravity model is MuJoCo's gravity torque (qfrc_bias at rest) on the rigid
    nominal plant: at home, at zero and at seeded postures within the joints' ranges."""
    rng = np.random.default_rng(0)
    limits = np.asarray(robot.limits.position)
    postures = [
        np.asarray(robot.workspace.home, dtype=float),
        np.zeros(len(limits)),
        *rng.uniform(-0.8 * limits, 0.8 * limits, size=(GRAVITY_POSTURES, len(limits))),
    ]
    with findable(robot):
        spec = nominal(robot, joints="rigid").model_copy(update={"interface": "fri"})
        model = robot.build(spec)
        data = mujoco.MjData(model)
        gravity = RobotGravity(spec)
        for q in postures:
            data.qpos[:] = q
            data.qvel[:] = 0.0
            mujoco.mj_forward(model, data)
            ours = gravity.at(q[None, :])[0]
            np.testing.assert_allclose(
                ours,
                data.qfrc_bias,
                rtol=GRAVITY_TOLERANCE,
                atol=GRAVITY_TOLERANCE,
                err_msg=f"gravity model at {np.round(q, 3).tolist()}",
            )


def check_workspace(robot: Robot) -> None:
    """The default trajectory's centre lies in the workspace, and a default spiral around its
    centre and each of its corners is reached, the tool pointing down, by the worker's inverse
    kinematics from home."""
    workspace = robot.workspace
    assert workspace.contains(workspace.center), "the workspace's centre lies outside it"
    with findable(robot):
        model = robot.build(nominal(robot, joints="rigid"))
        u = np.linspace(0.0, 1.0, PATH_SAMPLES)
        home = np.asarray(workspace.home, dtype=float)
        for point in (workspace.center, *workspace.corners()):
            path = TrajectorySpec(center=point)
            try:
                solve_path(model, robot.flange, path_points(path, u), tool_rotations(path, u), home)
            except UnreachablePath as error:
                raise AssertionError(f"workspace point {point}: {error}") from None


def check_references(robot: Robot) -> None:
    """Every built-in kind's default reference on the robot (TrajectorySpec's defaults, centred
    on the workspace centre, at the kind's default duration on the robot: 5 s, or longer where
    the arm needs it, within the spec's bounds) is built by the worker, stays within the joints'
    ranges and uses at most DEFAULT_SHARE (0.9) of each joint's speed and acceleration limit."""
    with findable(robot):
        arm = arm_of(robot.name)
        try:
            for kind in TrajectoryKind:
                spec = TrajectorySpec(kind=kind.value, center=robot.workspace.center)
                try:
                    duration = default_duration(spec, robot.name)
                    assert duration <= MAX_DURATION, (
                        f"the default {kind.value}: {duration:g} s to stay within "
                        f"{DEFAULT_SHARE:g} of the limits, beyond {MAX_DURATION:g} s"
                    )
                    spec = spec.model_copy(update={"duration": duration})
                    reference = reference_for(spec, robot.name)
                except (UnreachablePath, InfeasibleReference) as error:
                    raise AssertionError(f"the default {kind.value}: {error}") from None
                outside = (reference.q < arm.low) | (reference.q > arm.high)
                assert not outside.any(), (
                    f"the default {kind.value}: {arm.joint(int(outside.any(axis=0).argmax()))} "
                    "leaves its range"
                )
                for values, limits, what, bound in (
                    (reference.qd, arm.speed, "speed limit", DEFAULT_SHARE),
                    (reference.qdd, arm.acceleration, "acceleration limit", DEFAULT_SHARE),
                ):
                    share = np.abs(values).max(axis=0) / limits
                    joint = int(share.argmax())
                    assert share[joint] <= bound, (
                        f"the default {kind.value}: {arm.joint(joint)} at {share[joint]:.2f} "
                        f"of its {what} (at most {bound:g})"
                    )
        finally:  # a robot registered for the checks only leaves nothing cached of it
            forget_robots()


CHECKS: tuple[Callable[[Robot], None], ...] = (
    check_name,
    check_limits,
    check_members,
    check_builds,
    check_holds_still,
    check_gravity,
    check_workspace,
    check_references,
)


def check_robot(robot: Robot) -> None:
    """Every check, in order: the first failing one raises."""
    for check in CHECKS:
        check(robot)


class RobotChecks:
    """Every check as a pytest test: subclass it and give the subclass a `robot` fixture."""

    def test_name(self, robot: Robot) -> None:
        check_name(robot)

    def test_limits(self, robot: Robot) -> None:
        check_limits(robot)

    def test_members(self, robot: Robot) -> None:
        check_members(robot)

    def test_builds(self, robot: Robot) -> None:
        check_builds(robot)

    def test_holds_still(self, robot: Robot) -> None:
        check_holds_still(robot)

    def test_gravity(self, robot: Robot) -> None:
        check_gravity(robot)

    def test_workspace(self, robot: Robot) -> None:
        check_workspace(robot)

    def test_references(self, robot: Robot) -> None:
        check_references(robot)


def nominal(robot: Robot, joints: str) -> PlantSpec:
    """The robot's nominal plant with `joints`, nothing else of a variant: no friction, exact
    sensors, the motor torque commanded."""
    return PlantSpec(
        robot=robot.name,
        joints=joints,  # type: ignore[arg-type]
        friction=None,
        delay=0,
        interface="torque",
    )


def standing(robot: Robot, spec: EpisodeSpec) -> Reference:
    """A reference standing at the robot's home for the spec's duration, but for its first
    tick, NUDGE off it on every joint: where the plant starts."""
    ticks = spec.trajectory.ticks
    home = np.asarray(robot.workspace.home, dtype=float)
    model = robot.build(nominal(robot, joints="rigid"))
    data = mujoco.MjData(model)
    data.qpos[:] = home
    mujoco.mj_kinematics(model, data)
    flange = data.site(robot.flange).xpos.copy()
    still = np.zeros((ticks, len(home)))
    angles = np.tile(home, (ticks, 1))
    angles[0] += NUDGE
    return Reference(
        t=np.arange(ticks) * CONTROL_PERIOD,
        ee=np.tile(flange, (ticks, 1)),
        q=angles,
        qd=still,
        qdd=still.copy(),
    )


@contextmanager
def findable(robot: Robot) -> Iterator[None]:
    """The robot found by its name (the worker's plant looks it up so): the installed or
    built-in plug-in of that name must be this one; if there is none, it is registered in this
    process for the block."""
    try:
        found = plugins.load(plugins.ROBOTS, robot.name)
    except plugins.PluginError:
        found = None
    if found is robot:
        yield
        return
    assert found is None, f"{robot.name!r} names another robot here ({found!r}): rename it"
    plugins.register(plugins.ROBOTS, robot.name, robot)
    try:
        yield
    finally:
        plugins.unregister(plugins.ROBOTS, robot.name)
