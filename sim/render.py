"""Offscreen rendering of a run into an MP4, with the paths drawn into the MuJoCo scene.

The OpenGL back-end is ``MUJOCO_GL`` (``egl`` unless the user set it; see ``sim.gl``). Frames
are taken at a fixed rate of simulated time (``fps``), independent of the control rate: frame k
shows the state at t_k = k / fps. Overlays are MuJoCo user geoms added to the ``mjvScene``
after ``mjv_updateScene``: polylines (capsule connectors), arrows and spheres.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import mujoco
import numpy as np
from tqdm import tqdm

from sim.errors import RenderError

WIDTH, HEIGHT, FPS = 640, 480, 30.0


# ---------------------------------------------------------------- overlays
@dataclass(frozen=True)
class Polyline:
    """A curve through points, shape (K, 3) (world, m), drawn as line segments ``width`` pixels wide
    (lines cost a software renderer far less than capsules)."""

    points: np.ndarray
    rgba: tuple[float, float, float, float]
    width: float = 3.0


@dataclass(frozen=True)
class Arrow:
    """An arrow from ``start``, shape (3,), along ``vector``, shape (3,) (both m, world)."""

    start: np.ndarray
    vector: np.ndarray
    rgba: tuple[float, float, float, float] = (0.9, 0.1, 0.1, 1.0)
    radius: float = 0.006


@dataclass(frozen=True)
class Sphere:
    """A sphere of ``radius`` m at ``center``, shape (3,)."""

    center: np.ndarray
    radius: float
    rgba: tuple[float, float, float, float]


Overlay = Polyline | Arrow | Sphere


def decimate(points: np.ndarray, max_points: int) -> np.ndarray:
    """At most ``max_points`` of points, shape (K, 3), evenly spaced in index, ends kept."""
    if len(points) <= max_points:
        return points
    idx = np.unique(np.linspace(0, len(points) - 1, max_points).round().astype(int))
    return points[idx]


def _add_geom(scene: mujoco.MjvScene) -> mujoco.MjvGeom:
    if scene.ngeom >= scene.maxgeom:
        raise RenderError(f"too many overlay geoms for the scene (maxgeom {scene.maxgeom})")
    g = scene.geoms[scene.ngeom]
    scene.ngeom += 1
    return g


def draw(scene: mujoco.MjvScene, overlay: Overlay) -> None:
    """Append the user geoms of one overlay to ``scene``."""
    rgba = np.asarray(overlay.rgba, dtype=np.float32)
    eye = np.eye(3).ravel()
    if isinstance(overlay, Polyline):
        pts = np.asarray(overlay.points, dtype=np.float64)
        for a, b in zip(pts[:-1], pts[1:]):
            if np.linalg.norm(b - a) < 1e-9:
                continue
            g = _add_geom(scene)
            mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), eye, rgba)
            mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, overlay.width, a, b)
    elif isinstance(overlay, Arrow):
        start = np.asarray(overlay.start, dtype=np.float64)
        g = _add_geom(scene)
        mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_ARROW, np.zeros(3), np.zeros(3), eye, rgba)
        mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_ARROW, overlay.radius, start,
                             start + np.asarray(overlay.vector, dtype=np.float64))
    else:
        g = _add_geom(scene)
        mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_SPHERE, np.full(3, overlay.radius),
                            np.asarray(overlay.center, dtype=np.float64), eye, rgba)


# ---------------------------------------------------------------- camera
def framing_camera(points: np.ndarray, base: np.ndarray, normal: np.ndarray | None = None,
                   fovy_deg: float = 45.0) -> mujoco.MjvCamera:
    """A free camera framing the workspace: it looks at the centre c of ``points``, shape (K, 3),
    from the side away from the robot ``base``, shape (3,), 35 deg to the side of the line
    base -> c, from above (looking down on a horizontal task plane, i.e. ``normal`` ~ z, at
    45 deg, else at 25 deg), and far enough to show the path and the forearm of the robot:
    distance = max(2.2 size / tan(fovy / 2), 0.85 |base - c|, 0.3 m)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = pts.min(0), pts.max(0)
    c = (lo + hi) / 2
    size = float(np.max(hi - lo))
    toward = base - c
    toward[2] = 0.0
    az = math.degrees(math.atan2(toward[1], toward[0])) if np.linalg.norm(toward) > 1e-6 else 180.0
    flat = normal is not None and abs(float(np.asarray(normal)[2])) > 0.7
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = c
    cam.azimuth = az + 35.0
    cam.elevation = -45.0 if flat else -25.0
    reach = float(np.linalg.norm(base - c))
    cam.distance = max(2.2 * size / math.tan(math.radians(fovy_deg) / 2), 0.85 * reach, 0.3)
    return cam


# ---------------------------------------------------------------- GL context + renderer
def open_gl_context(width: int, height: int):  # -> mujoco GLContext
    """An offscreen OpenGL context of the back-end named by ``MUJOCO_GL``, made current."""
    backend = os.environ.get("MUJOCO_GL", "egl").lower().strip()
    try:
        if backend == "egl":
            from mujoco.egl import GLContext
        elif backend == "osmesa":
            from mujoco.osmesa import GLContext
        elif backend in ("glfw", "glx", "1", "on", "true", "enable", "enabled", ""):
            from mujoco.glfw import GLContext
        else:
            raise RenderError(f"MUJOCO_GL={backend} cannot render offscreen; use egl or osmesa")
        ctx = GLContext(width, height)
        ctx.make_current()
        return ctx
    except RenderError:
        raise
    except Exception as e:  # the back-ends raise ImportError, RuntimeError, OSError, GL errors
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        hint = ("install libegl1 (EGL) or libosmesa6 and set MUJOCO_GL=osmesa"
                if backend == "egl" else "install it, or try MUJOCO_GL=egl")
        raise RenderError(f"cannot open an OpenGL context with MUJOCO_GL={backend} ({first}); {hint}") from None


class SceneRenderer:
    """Renders MjData states with overlays into RGB images, shape (height, width, 3), uint8,
    without shadows, reflections and skybox.

    Use as a context manager (or call ``close``) so the GL context is freed before exit.
    """

    def __init__(self, model: mujoco.MjModel, width: int = WIDTH, height: int = HEIGHT,
                 max_geom: int = 4000) -> None:
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
        self.model, self.width, self.height = model, width, height
        self._ctx = open_gl_context(width, height)
        self.scene = mujoco.MjvScene(model, maxgeom=max_geom)
        # Shadows, reflections and the skybox cost a software (llvmpipe) renderer ~5x the frame time.
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION,
                     mujoco.mjtRndFlag.mjRND_SKYBOX):
            self.scene.flags[flag] = False
        self.option = mujoco.MjvOption()
        self._mjr = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._mjr)
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._pixels = np.empty((height, width, 3), dtype=np.uint8)

    def render(self, data: mujoco.MjData, camera: mujoco.MjvCamera,
               overlays: Sequence[Overlay] = (), robot_alpha: float = 1.0) -> np.ndarray:
        """One image of ``data`` (kinematics already computed) seen by ``camera``; the moving
        bodies are drawn with opacity ``robot_alpha`` (< 1 lets the paths show through the arm)."""
        mujoco.mjv_updateScene(self.model, data, self.option, None, camera,
                               mujoco.mjtCatBit.mjCAT_ALL, self.scene)
        if robot_alpha < 1.0:
            dynamic = mujoco.mjtCatBit.mjCAT_DYNAMIC
            for i in range(self.scene.ngeom):
                g = self.scene.geoms[i]
                if g.category & dynamic:
                    g.rgba[3] *= robot_alpha
        for o in overlays:
            draw(self.scene, o)
        mujoco.mjr_render(self._rect, self.scene, self._mjr)
        mujoco.mjr_readPixels(self._pixels, None, self._rect, self._mjr)
        return np.flipud(self._pixels).copy()

    def close(self) -> None:
        if self._mjr is not None:
            self._mjr.free()
            self._mjr = None
        if self._ctx is not None:
            self._ctx.free()
            self._ctx = None

    def __enter__(self) -> "SceneRenderer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------- video
def frame_times(duration_s: float, fps: float = FPS) -> np.ndarray:
    """t_k = k / fps for k = 0 .. floor(duration fps), shape (K,)."""
    return np.arange(int(math.floor(duration_s * fps + 1e-9)) + 1) / fps


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], width: int, height: int,
                fps: float = FPS) -> int:
    """Encode RGB frames, each shape (height, width, 3) uint8, as H.264 MP4 at ``fps``; the file
    appears atomically (temporary file, then rename). Returns the number of frames written."""
    import imageio_ffmpeg
    import mediapy

    mediapy.set_ffmpeg(imageio_ffmpeg.get_ffmpeg_exe())
    p = Path(path)
    n = 0
    tmp: str | None = None
    try:  # the temporary file goes on any exception, KeyboardInterrupt (Ctrl-C, SIGTERM) included
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=".mp4", dir=p.parent)
        os.close(fd)
        with mediapy.VideoWriter(tmp, shape=(height, width), fps=fps, crf=23) as w:
            for f in frames:
                w.add_image(f)
                n += 1
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)   # mkstemp makes the file private; a video is not
        os.replace(tmp, p)
    except (OSError, RuntimeError, ValueError) as e:
        if _interrupted(e):  # Ctrl-C also killed ffmpeg, and closing it then failed
            raise KeyboardInterrupt from None
        raise RenderError(f"{path}: cannot write the video ({(str(e).splitlines() or [''])[0]})") from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    return n


# ---------------------------------------------------------------- a whole run
DEMO_RGBA = (0.15, 0.35, 0.95, 0.9)
TRACE_RGBA = (1.0, 0.55, 0.0, 1.0)
GOAL_RGBA = (0.1, 0.75, 0.2, 1.0)
PUSH_RGBA = (0.9, 0.1, 0.1, 1.0)
ARROW_M_PER_N = 0.005
ROBOT_ALPHA = 0.5


def render_rollout(model: mujoco.MjModel, rollout, demo_world: np.ndarray, path: str | os.PathLike,
                   base: np.ndarray, normal: np.ndarray | None = None, width: int = WIDTH,
                   height: int = HEIGHT, fps: float = FPS, progress: bool = False) -> int:
    """Write the MP4 of a ``sim.rollout.Rollout``: one frame per ``rollout.frame_t`` (a fixed
    rate of simulated time), the arm half transparent (``ROBOT_ALPHA``) so that it does not hide
    the paths, drawn with the demonstration (blue, demo_world : (T, 3) m), the
    tool trace so far (orange), the goal (green sphere) and, during a push (and 0.1 s after), an
    arrow along the force ending at the pushed body's centre of mass (red, ``ARROW_M_PER_N`` m
    per N), plus a red dot on the trace where the push began.
    Returns the number of frames."""
    data = mujoco.MjData(model)
    cam = framing_camera(np.concatenate([demo_world, rollout.ee]), base, normal)
    span = float(np.max(np.ptp(np.concatenate([demo_world, rollout.ee]), axis=0)))
    radius = max(0.0008, 0.008 * span)
    px = width / 640.0
    static: list[Overlay] = [Polyline(decimate(demo_world, 200), DEMO_RGBA, 4.0 * px),
                             Sphere(rollout.goal_world, 2.5 * radius, GOAL_RGBA)]
    window = rollout.push_window_s
    k_push = None if window is None else int(np.searchsorted(rollout.t, window[0]))
    dt = float(rollout.t[1] - rollout.t[0])

    def frames() -> Iterable[np.ndarray]:
        states = tqdm(zip(rollout.frame_t, rollout.frame_qpos), total=len(rollout.frame_t), desc="video",
                      unit="frame", disable=not progress, leave=False)
        with SceneRenderer(model, width, height) as r:
            for t, qpos in states:
                data.qpos[:] = qpos
                mujoco.mj_forward(model, data)
                k = min(int(round(t / dt)), len(rollout.ee) - 1)
                overlays = list(static)
                if k > 0:
                    overlays.append(Polyline(decimate(rollout.ee[:k + 1], 300), TRACE_RGBA, 5.0 * px))
                if window is not None and k >= k_push:
                    overlays.append(Sphere(rollout.ee[k_push], 1.8 * radius, PUSH_RGBA))
                    if window[0] - 1e-9 <= t < window[1] + 0.1:
                        vec = ARROW_M_PER_N * rollout.push_force
                        overlays.append(Arrow(data.xipos[rollout.push_body] - vec, vec, PUSH_RGBA, 4.0 * radius))
                yield r.render(data, cam, overlays, ROBOT_ALPHA)

    return write_video(path, frames(), width, height, fps)


def _interrupted(e: BaseException) -> bool:
    """Whether a KeyboardInterrupt is among the exceptions that led to ``e``."""
    seen: set[int] = set()
    cur: BaseException | None = e
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, KeyboardInterrupt):
            return True
        seen.add(id(cur))
        cur = cur.__context__
    return False
