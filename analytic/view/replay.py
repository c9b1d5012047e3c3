"""`analytic replay`: an episode log as a video of the arm following its path.

MuJoCo draws the arm the log names (its plant's robot: the robot's own rigid model, whatever its
joints) at the logged joint angles, offscreen, with the reference path (the logged
desired flange positions, green) and the path the flange took so far (magenta) added to its
scene, and the time and tracking error written in a corner; PyAV (FFmpeg's libx264, in the
`render` extra) encodes the frames as H.264 in an MP4. The video is made in memory and written
whole (a temporary file, then a rename), so a failed replay leaves no half-written MP4.

The frames are drawn with MuJoCo's own rendering calls rather than `mujoco.Renderer`, whose
OpenGL backend is chosen once, from MUJOCO_GL, when mujoco is first imported: a process without
a display that did not set it gets GLFW, which cannot draw. Here the backend is chosen when the
replay starts: MUJOCO_GL if it names one, else EGL, which Mesa provides without a display or a
GPU (Debian: libegl1, libegl-mesa0, libgl1-mesa-dri).
"""

import importlib
import io
import itertools
import os
import tempfile
from pathlib import Path

import mujoco
import numpy as np

from gainfarm.edges.files import write_atomically
from gainfarm.models import robot_of
from gainfarm.plugins import PluginError
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, read_episode
from gainfarm.schemas.robot import PlantSpec

DEFAULT_FPS = 30
DEFAULT_WIDTH, DEFAULT_HEIGHT = 640, 480
BACKENDS = ("egl", "osmesa", "glfw")
DEBIAN_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri"
REFERENCE_RGBA = (0.1, 0.85, 0.1, 1.0)  # the reference path: green, a colour the scene lacks
ACHIEVED_RGBA = (0.85, 0.1, 0.85, 1.0)  # the path taken: magenta
MARKER_RADIUS = 0.012  # m, the sphere at the current desired point
MAX_SEGMENTS = 400  # per path: enough for a smooth curve, few enough for the scene's geoms
# Looking at the arm and the paths in front of it, from the front left and a little above.
CAMERA = {"lookat": (0.35, 0.0, 0.35), "distance": 1.5, "azimuth": 135.0, "elevation": -35.0}
# The close-up in the frame's bottom-right corner: a camera the same way round, looking at the
# middle of the desired point and the flange from three times their distance (4 cm to 60 cm),
# so that the error fills a third of it whatever its size: millimetres are pixels apart there,
# where the whole view, from 1.5 m, shows a few. The arm is see-through in it: from this close it
# would hide the point it is at.
INSET = {"azimuth": 135.0, "elevation": -35.0}
INSET_DISTANCE = (3.0, 0.04, 0.6)  # times the error, at least, at most (m)
INSET_ALPHA = 0.25
INSET_SHARE = 0.36  # of the frame's width and height
INSET_MARKER = 0.025  # the markers' radius in the close-up, as a share of its distance
FLANGE_RGBA = (1.0, 1.0, 1.0, 1.0)  # where the flange is, in the close-up: white
# An arm's geoms its model leaves MuJoCo's default grey (Menagerie's collision shapes, whose
# meshes are not vendored) are drawn in the iiwa's orange: grey on the grey floor is hard to see.
DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)
ARM_RGBA = (0.9, 0.45, 0.1, 1.0)
BONE_RADIUS = 0.035  # m: a link without a shape of its own, drawn as a bone (`_bones`)


class ReplayError(ValueError):
    """Why a replay cannot be made, in one line."""


def replay(
    log_path: Path,
    out: Path,
    fps: int = DEFAULT_FPS,
    width: int = DEFAULT_WIDTH,
    height: int = DEFAULT_HEIGHT,
    robot: str | None = None,
) -> int:
    """Render the episode at `log_path` to the MP4 `out`; return the number of frames. `robot`:
    the arm the log must be of (None: whichever it names)."""
    if width % 2 or height % 2:  # H.264 in 4:2:0 halves the colour planes
        raise ReplayError(f"{'--width' if width % 2 else '--height'}: must be even")
    _check_writable(Path(out))
    try:
        log = read_episode(log_path)
    except NotAnEpisodeLog as error:
        raise ReplayError(str(error)) from None
    except OSError as error:
        raise ReplayError(f"{str(log_path)!r}: {error.strerror or error}") from None
    if log.ticks == 0:
        raise ReplayError(f"{log_path}: the episode ran no tick: nothing to show")
    arm = log.metadata.spec.plant.robot
    if robot is not None and robot != arm:
        raise ReplayError(f"--robot: {str(log_path)!r} is an episode of {arm}, not of {robot}")
    try:
        robot_of(arm)
    except PluginError:
        raise ReplayError(
            f"LOG: {str(log_path)!r} is an episode of {arm!r}, an arm not installed here: give "
            "its description file, --robot FILE"
        ) from None
    ticks = frame_ticks(log.t, fps)
    video = encode(render(log, ticks, width, height), fps, width, height)
    try:
        write_atomically(Path(out), video)
    except OSError as error:
        raise ReplayError(f"--out: cannot write {str(out)!r}: {error.strerror or error}") from None
    return len(ticks)


def frame_ticks(t: np.ndarray, fps: int) -> np.ndarray:
    """The tick each frame shows: frame k is time k / fps, and shows the last tick at or before
    it; the frames run from t = 0 to the episode's last tick."""
    times = np.arange(int(np.floor(t[-1] * fps + 1e-9)) + 1) / fps
    return np.searchsorted(t, times + 1e-9, side="right") - 1


def render(log: EpisodeLog, ticks: np.ndarray, width: int, height: int) -> list[np.ndarray]:
    """The frames (height, width, 3 uint8), one per tick of `ticks`, of the arm the log names."""
    robot = log.metadata.spec.plant.robot
    model = _scene_model(robot, width, height)
    data = mujoco.MjData(model)
    hinges = [model.joint(name).qposadr[0] for name in robot_of(robot).joint_names]
    reference = _path(log.ee_des)
    line_width = max(2.0, height / 160)  # pixels: 3 at 480 lines
    context = _gl_context(width, height)
    try:
        context.make_current()
        graphics = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, graphics)
        scene = mujoco.MjvScene(model, maxgeom=1000 + 2 * MAX_SEGMENTS)
        camera, option = mujoco.MjvCamera(), mujoco.MjvOption()
        option.geomgroup[:] = 1  # every group: an arm's shapes may be in any (UR5e's in 3)
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        for name, value in CAMERA.items():
            setattr(camera, name, value)
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0  # see _scene_model
        viewport = mujoco.MjrRect(0, 0, width, height)
        close = mujoco.MjvCamera()
        close.type = mujoco.mjtCamera.mjCAMERA_FREE
        for name, value in INSET.items():
            setattr(close, name, value)
        inset_w, inset_h = int(width * INSET_SHARE), int(height * INSET_SHARE)
        margin = max(2, width // 80)
        # OpenGL's rows run bottom up: the bottom-right corner, inside a white border.
        inset = mujoco.MjrRect(width - inset_w - margin, margin, inset_w, inset_h)
        border = mujoco.MjrRect(inset.left - 2, inset.bottom - 2, inset_w + 4, inset_h + 4)
        frames = []
        for tick in ticks:
            data.qpos[hinges] = log.q[tick]
            mujoco.mj_forward(model, data)
            mujoco.mjv_updateScene(
                model, data, option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene
            )
            _add_line(scene, reference, line_width, REFERENCE_RGBA)
            _add_line(scene, _path(log.ee[: tick + 1]), line_width, ACHIEVED_RGBA)
            _add_sphere(scene, log.ee_des[tick], MARKER_RADIUS, REFERENCE_RGBA)
            mujoco.mjr_render(viewport, scene, graphics)
            error = np.linalg.norm(log.ee[tick] - log.ee_des[tick]) * 1000
            mujoco.mjr_overlay(
                mujoco.mjtFont.mjFONT_NORMAL,
                mujoco.mjtGridPos.mjGRID_TOPLEFT,
                viewport,
                "t\nerror",
                f"{log.t[tick]:.2f} s\n{error:.1f} mm",
                graphics,
            )
            # The close-up: the same paths about the error, the flange a white dot.
            scale, nearest, farthest = INSET_DISTANCE
            close.lookat[:] = (log.ee_des[tick] + log.ee[tick]) / 2
            close.distance = float(np.clip(scale * error / 1000, nearest, farthest))
            mujoco.mjv_updateScene(
                model, data, option, None, close, mujoco.mjtCatBit.mjCAT_ALL, scene
            )
            for geom in range(scene.ngeom):  # the arm and the floor, see-through
                scene.geoms[geom].rgba[3] = INSET_ALPHA
            _add_line(scene, reference, line_width, REFERENCE_RGBA)
            _add_line(scene, _path(log.ee[: tick + 1]), line_width, ACHIEVED_RGBA)
            marker = INSET_MARKER * close.distance
            _add_sphere(scene, log.ee_des[tick], marker, REFERENCE_RGBA)
            _add_sphere(scene, log.ee[tick], marker, FLANGE_RGBA)
            mujoco.mjr_rectangle(border, 1.0, 1.0, 1.0, 1.0)
            mujoco.mjr_render(inset, scene, graphics)
            mujoco.mjr_overlay(
                mujoco.mjtFont.mjFONT_NORMAL,
                mujoco.mjtGridPos.mjGRID_TOPLEFT,
                inset,
                "close-up",
                f"from {close.distance * 100:.0f} cm",
                graphics,
            )
            pixels = np.empty((height, width, 3), np.uint8)
            mujoco.mjr_readPixels(pixels, None, viewport, graphics)
            frames.append(np.flipud(pixels))  # OpenGL's rows run bottom up
        graphics.free()
    finally:
        context.free()
    return frames


def encode(frames: list[np.ndarray], fps: int, width: int, height: int) -> bytes:
    """The frames as an H.264 MP4, in memory."""
    try:
        import av  # optional extra: render
    except ImportError:
        raise ReplayError("encoding the video needs PyAV: pip install 'gainfarm[render]'") from None
    buffer = io.BytesIO()
    with av.open(buffer, mode="w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": "20"}  # the paths are thin lines: a little above the default
        for frame in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
        container.mux(stream.encode())  # flush the encoder's delayed frames
    return buffer.getvalue()


def _check_writable(out: Path) -> None:
    """Refuse an --out that cannot be written before spending time on the frames: a temporary
    file made and removed beside it says so (permissions, a read-only file system)."""
    if out.is_dir():
        raise ReplayError(f"--out: {str(out)!r} is a directory")
    if not out.parent.is_dir():
        raise ReplayError(f"--out: no directory {str(out.parent)!r} to write {out.name!r} in")
    try:
        with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", suffix=".part"):
            pass
    except OSError as error:
        raise ReplayError(f"--out: cannot write {str(out)!r}: {error.strerror or error}") from None


def _scene_model(robot: str, width: int, height: int) -> mujoco.MjModel:
    """The rigid arm `robot` names (every variant's bodies and geoms), on a floor under a sky,
    with an offscreen buffer of the video's size."""
    spec = robot_of(robot).describe(PlantSpec(robot=robot, joints="rigid"))
    for geom in spec.geoms:
        if tuple(geom.rgba) == DEFAULT_RGBA and not geom.material:
            geom.rgba = ARM_RGBA
    _bones(spec.worldbody)
    if not spec.lights:  # lit as the iiwa's model is (Menagerie's files leave their lights out)
        spec.worldbody.add_light(pos=[0.0, 0.0, 3.0], dir=[0.0, 0.0, -1.0])
    spec.visual.global_.offwidth, spec.visual.global_.offheight = width, height
    spec.add_texture(
        name="sky",
        type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        rgb1=[0.55, 0.6, 0.7],
        rgb2=[0.1, 0.1, 0.12],
        width=256,
        height=256,
    )
    spec.add_texture(
        name="grid",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.32, 0.32, 0.34],
        rgb2=[0.42, 0.42, 0.44],
        width=256,
        height=256,
    )
    floor = spec.add_material(name="floor", texrepeat=[8, 8])
    floor.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[1.5, 1.5, 0.05],
        material="floor",
        rgba=[1, 1, 1, 1],  # not the MJCF's default geom colour: the texture's own
    )
    # Software OpenGL (Mesa's llvmpipe) draws a 640 × 480 frame of this scene in about 60 ms;
    # multisampling would add 130 ms (reading the frame back) and shadows 120 ms.
    spec.visual.quality.offsamples = 0
    model = spec.compile()
    return model


def _bones(parent: mujoco.MjsBody) -> None:
    """A link its model gives no shape (a model vendored without its meshes, as Menagerie's
    Gen3) drawn as a bone: a capsule from its origin to each of its links', a ball if it has
    none; so that every arm shows, whatever its file draws. Visual only: contacts are off."""
    for body in parent.bodies:
        if not body.geoms:
            ends = [np.asarray(child.pos, dtype=float) for child in body.bodies]
            for end in ends:
                if np.linalg.norm(end) > BONE_RADIUS:
                    body.add_geom(
                        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                        fromto=[0.0, 0.0, 0.0, *end],
                        size=[BONE_RADIUS, 0.0, 0.0],
                        rgba=ARM_RGBA,
                        contype=0,
                        conaffinity=0,
                        density=0.0,
                    )
            if not body.geoms:
                body.add_geom(
                    type=mujoco.mjtGeom.mjGEOM_SPHERE,
                    size=[BONE_RADIUS, 0.0, 0.0],
                    rgba=ARM_RGBA,
                    contype=0,
                    conaffinity=0,
                    density=0.0,
                )
        _bones(body)


def _gl_context(width: int, height: int) -> object:
    """An OpenGL context to draw offscreen in: MUJOCO_GL's backend if it names one, else EGL."""
    backend = os.environ.get("MUJOCO_GL", "").strip().lower()
    if backend not in BACKENDS:
        backend = "egl"
    try:
        return importlib.import_module(f"mujoco.{backend}").GLContext(width, height)
    except Exception as error:  # whatever the platform's libraries raise when they are missing
        reason = " ".join(f"{type(error).__name__}: {error}".split())[:200]
        raise ReplayError(
            f"no offscreen OpenGL ({backend}: {reason}); on Debian install {DEBIAN_PACKAGES}"
        ) from None


def _path(points: np.ndarray) -> np.ndarray:
    """At most MAX_SEGMENTS + 1 of `points`, evenly spaced, the last one kept."""
    if len(points) <= MAX_SEGMENTS + 1:
        return points
    index = np.unique(np.linspace(0, len(points) - 1, MAX_SEGMENTS + 1).round().astype(int))
    return points[index]


def _add_line(
    scene: mujoco.MjvScene, points: np.ndarray, width: float, rgba: tuple[float, ...]
) -> None:
    """Line segments (`width` pixels wide) joining consecutive `points`: OpenGL lines are
    unlit, so their colour stays, and cost a tenth of the same path drawn as capsules."""
    colour = np.array(rgba, dtype=np.float32)
    for start, end in itertools.pairwise(points):
        if scene.ngeom == scene.maxgeom:
            return
        geom = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(
            geom, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), colour
        )
        mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_LINE, width, start, end)
        scene.ngeom += 1


def _add_sphere(
    scene: mujoco.MjvScene, centre: np.ndarray, radius: float, rgba: tuple[float, ...]
) -> None:
    if scene.ngeom == scene.maxgeom:
        return
    geom = scene.geoms[scene.ngeom]
    size = np.array([radius, radius, radius])
    mujoco.mjv_initGeom(
        geom, mujoco.mjtGeom.mjGEOM_SPHERE, size, centre, np.eye(3).ravel(), np.array(rgba)
    )
    geom.emission = 0.5
    scene.ngeom += 1
