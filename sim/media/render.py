"""Offscreen rendering of runs into MP4s: one run, or several side by side in one video.

The OpenGL back-end is ``MUJOCO_GL`` (``egl`` unless the user set it; see ``sim.media.gl``). Frames
are taken at a fixed rate of simulated time (``fps``), independent of the control rate: frame k
shows the state at t_k = k / fps. The scene is drawn without shadows, reflections, skybox and
multisampling (each costs a software renderer, llvmpipe, a large share of its frame time); the
paths, legend and labels are then drawn into the image in 2-D (``sim.media.overlay``, projected with
``sim.media.camera.project``), on top of the arm. MuJoCo user geoms (``Polyline``, ``Arrow``,
``Sphere``, drawn in 3-D inside the scene) remain available through ``SceneRenderer.render``.
Several panels share one GL context and one encoder (``render_panels``), and successive videos
of one model share one GL context (``shared_renderer``).
"""

from __future__ import annotations

import atexit
import math
import os
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from PIL import Image
from tqdm import tqdm

from lfd.io import atomic_path
from sim.control.loop import FPS, frame_times
from sim.errors import RenderError
from sim.media.camera import CameraSpec, Projector, fixed_camera, task_camera
from sim.media.overlay import FrameText, StaticLayer, draw_dynamic, draw_frames, draw_static, tile

WIDTH, HEIGHT = 640, 480


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
                 max_geom: int = 4000, samples: int = 0) -> None:
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
        model.vis.quality.offsamples = samples  # MSAA (off by default) is expensive on llvmpipe
        self.model, self.width, self.height = model, width, height
        self._ctx = open_gl_context(width, height)
        self.scene = mujoco.MjvScene(model, maxgeom=max_geom)
        # Shadows, reflections and the skybox cost a software (llvmpipe) renderer most of its frame time.
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION,
                     mujoco.mjtRndFlag.mjRND_SKYBOX):
            self.scene.flags[flag] = False
        self.option = mujoco.MjvOption()
        self._mjr = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._mjr)
        _nearest_mipmap(self._mjr)
        self.resize(width, height)

    def resize(self, width: int, height: int) -> None:
        """Render width x height images from now on, at most the offscreen buffer's size (the
        model's ``vis.global_.offwidth`` x ``offheight`` when the renderer was made)."""
        if width > self._mjr.offWidth or height > self._mjr.offHeight:
            raise RenderError(f"{width}x{height} exceeds the renderer's {self._mjr.offWidth}x{self._mjr.offHeight}")
        self.width, self.height = width, height
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

    @property
    def buffer_size(self) -> tuple[int, int]:
        """(width, height) of the offscreen buffer: the largest images this renderer makes."""
        return int(self._mjr.offWidth), int(self._mjr.offHeight)

    def make_current(self) -> None:
        """Make the renderer's GL context the calling thread's current one."""
        if self._ctx is not None:
            self._ctx.make_current()

    def close(self) -> None:
        if self._mjr is not None:
            self._mjr.free()
            self._mjr = None
        if self._ctx is not None:
            self._ctx.free()
            self._ctx = None

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _nearest_mipmap(mjr: mujoco.MjrContext) -> None:
    """Sample the 2-D textures (the floor's) from the nearest mipmap level instead of blending two
    (``GL_LINEAR_MIPMAP_NEAREST``): a software renderer (llvmpipe) then spends less time on a frame
    with a textured floor, and pixels barely change. Needs PyOpenGL
    (as MuJoCo's EGL and OSMesa back-ends do); without it, nothing changes."""
    try:
        from OpenGL import GL
    except ImportError:
        return
    for tex, kind in zip(mjr.texture[:mjr.ntexture], mjr.textureType[:mjr.ntexture]):
        if kind == mujoco.mjtTexture.mjTEXTURE_2D:
            GL.glBindTexture(GL.GL_TEXTURE_2D, int(tex))
            GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR_MIPMAP_NEAREST)
    GL.glBindTexture(GL.GL_TEXTURE_2D, 0)


# ---------------------------------------------------------------- one renderer kept between videos
_shared: SceneRenderer | None = None       # the renderer kept for the next video (one at a time)
_shared_owner: tuple[int, int] = (0, 0)    # (process id, thread id) that made it current
_release_at_exit: list[bool] = []          # [True] once release_shared_renderer runs at exit


def shared_renderer(model: mujoco.MjModel, width: int, height: int) -> SceneRenderer | None:
    """A ``SceneRenderer`` of ``model`` set to width x height, kept open for the next video:
    making one (a GL context, and ``MjrContext`` uploading meshes and textures) is slow on a
    software renderer. The one kept is reused when it is of the same model object and its
    offscreen buffer holds the size, else freed and replaced (so it keeps at most one model alive);
    it is freed at exit (``release_shared_renderer``). Returns None when the kept one belongs to another thread (its
    GL context is current there): the caller then makes its own."""
    global _shared, _shared_owner
    owner = (os.getpid(), threading.get_ident())
    r = _shared
    if r is not None and _shared_owner[0] != owner[0]:
        _shared = r = None                  # made before a fork: the parent's, not ours to free
    if r is not None and _shared_owner != owner:
        return None
    if r is not None and (r.model is not model or r.buffer_size[0] < width or r.buffer_size[1] < height):
        release_shared_renderer()
        r = None
    if r is None:
        r = SceneRenderer(model, width, height)
        _shared, _shared_owner = r, owner
        if not _release_at_exit:   # after the back-end's own exit hook (EGL's eglTerminate): runs before it
            atexit.register(release_shared_renderer)
            _release_at_exit.append(True)
    r.make_current()
    r.resize(width, height)
    return r


def release_shared_renderer() -> None:
    """Free the renderer that ``shared_renderer`` keeps (if any): forget it, and free its GL
    context when this thread made it (another process's or thread's is left to its owner's exit)."""
    global _shared
    r, _shared = _shared, None
    if r is not None and _shared_owner == (os.getpid(), threading.get_ident()):
        r.make_current()
        r.close()


# ---------------------------------------------------------------- video
def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], width: int, height: int,
                fps: float = FPS) -> int:
    """Encode RGB frames, each shape (height, width, 3) uint8, as H.264 MP4 at ``fps``; the file
    appears atomically (temporary file, then rename). Returns the number of frames written.

    x264's ``ultrafast`` preset at CRF 23: faster than ``veryfast`` for files a few times larger,
    because the encoder shares the CPU cores with llvmpipe."""
    import imageio_ffmpeg
    import mediapy

    mediapy.set_ffmpeg(imageio_ffmpeg.get_ffmpeg_exe())
    n = 0
    try:  # atomic_path removes the temporary file on any exception, KeyboardInterrupt (Ctrl-C, SIGTERM) included
        with atomic_path(path, suffix=".mp4") as tmp, \
                mediapy.VideoWriter(str(tmp), shape=(height, width), fps=fps, crf=23,
                                    ffmpeg_args=["-preset", "ultrafast"]) as w:
            for f in frames:
                w.add_image(f)
                n += 1
    except (OSError, RuntimeError, ValueError) as e:
        if _interrupted(e):  # Ctrl-C also killed ffmpeg, and closing it then failed
            raise KeyboardInterrupt from None
        raise RenderError(f"{path}: cannot write the video ({(str(e).splitlines() or [''])[0]})") from None
    return n


# ---------------------------------------------------------------- a whole run
PUSH_ARROW_FRACTION = 0.35   # the push arrow is this fraction of the path's size long
PATH_POINTS = 400            # most points per drawn path
DEMO_FRAMES = 12             # a pose task's demonstrated tool frames drawn along its path
FRAME_FRACTION = 0.08        # ... each axis this fraction of the path's size long (the live one twice)
AUTO_FOVY_DEG = 25.0         # the chosen camera is a long lens: the hand near it is not blown up


@dataclass(frozen=True)
class Panel:
    """What one panel of a video shows: a ``sim.control.loop.RunTrace``, the field's own rollout from the
    same start, ``reference`` (K+1, 3) world m (None: not drawn), its ``title`` and, for a goal that
    moves during the run, where the goal is at each control step, ``goal_path`` (K+1, 3) world m
    (None: the fixed ``RunTrace.goal_world``)."""

    trace: Any
    reference: np.ndarray | None
    title: str
    goal_path: np.ndarray | None = None


def panel_grid(n: int) -> tuple[int, int]:
    """(columns, rows) for n panels: one row up to 3, then as square as possible."""
    if n <= 3:
        return n, 1
    cols = int(math.ceil(math.sqrt(n)))
    return cols, int(math.ceil(n / cols))


def _frame_qpos(trace: Any, times: np.ndarray, nq: int, qpos_adr: np.ndarray) -> np.ndarray:
    """qpos, shape (F, nq), at ``times``: the run's recorded frames when they are these times,
    else its first frame with the arm joints (qpos addresses ``qpos_adr``, (n,)) from the control
    step nearest each time."""
    ft = np.asarray(trace.frame_t)
    if trace.frame_qpos.shape[1] != nq:
        raise RenderError("the run's qpos does not fit the model")
    if len(ft) >= len(times) and np.allclose(ft[:len(times)], times, atol=1e-9):
        return np.asarray(trace.frame_qpos[:len(times)])
    out = np.repeat(np.asarray(trace.frame_qpos[:1]), len(times), axis=0)
    out[:, qpos_adr] = trace.q[trace.steps_at(times)]
    return out


def _frame_mocap(trace: Any, times: np.ndarray, nmocap: int) -> np.ndarray | None:
    """The mocap bodies' positions (moving obstacles), shape (F, nmocap, 3), at ``times``, or None
    when the trace moved none."""
    path = trace.mocap_pos
    if path is None:
        return None
    if path.shape[1] != nmocap:
        raise RenderError("the run's mocap bodies do not fit the model")
    return np.asarray(path)[trace.steps_at(times)]


def _scene_points(model: mujoco.MjModel, qpos: list[np.ndarray], samples: int = 12) -> np.ndarray:
    """The bodies' origins (all but the world and the mocap obstacles), shape (M, 3), world, at
    ``samples`` of each panel's frames ``qpos`` (F, nq): what the camera keeps in view."""
    data = mujoco.MjData(model)
    bodies = [i for i in range(1, model.nbody) if model.body_mocapid[i] < 0]
    out = []
    for frames in qpos:
        for k in np.unique(np.linspace(0, len(frames) - 1, samples).round().astype(int)):
            data.qpos[:] = frames[k]
            mujoco.mj_kinematics(model, data)
            out.append(data.xpos[bodies].copy())
    return np.concatenate(out) if out else np.zeros((0, 3))


def render_panels(model: mujoco.MjModel, panels: Sequence[Panel], demo_world: np.ndarray,
                  path: str | os.PathLike, base: np.ndarray, qpos_adr: np.ndarray,
                  normal: np.ndarray | None = None, width: int = WIDTH, height: int = HEIGHT,
                  fps: float = FPS, camera: CameraSpec = CameraSpec(), progress: bool = False,
                  demo_rotations: np.ndarray | None = None) -> int:
    """Write one MP4 of ``width`` x ``height`` with the panels tiled (``panel_grid``), each panel
    (width / columns) x (height / rows) pixels (rounded down to even numbers), all seen by the same
    camera (``sim.media.camera.task_camera`` over every panel's path, or ``camera``) and rendered by one
    GL context, frame k at t_k = k / fps of simulated time.

    Each panel: the arm (visual meshes; collision geoms hidden), and drawn on top
    (``sim.media.overlay``) the demonstration ``demo_world`` (T, 3), the field's rollout, the robot's
    trace so far, the goal, the push arrow while the push acts (plus 0.1 s) and the point where
    it began, a legend, the title, the simulated time and the tracking error |p(t) - p_ref(t)|;
    moving obstacles where the run had them (``RunTrace.mocap_pos``). A pose task
    (``demo_rotations`` (T, 3, 3) given) also shows the demonstrated tool frame as small axes at
    ``DEMO_FRAMES`` points along the demonstration and the robot's tool frame live (x red, y green,
    z blue; from ``RunTrace.ee_rot``).
    qpos_adr : (n,) qpos addresses of the arm joints. Returns the number of frames.
    """
    if not panels:
        raise RenderError("nothing to render: no panels")
    cols, rows = panel_grid(len(panels))
    pw, ph = (width // cols) // 2 * 2, (height // rows) // 2 * 2
    if pw < 16 or ph < 16:
        raise RenderError(f"{width}x{height} is too small for {len(panels)} panels")
    duration = min(float(p.trace.t[-1]) for p in panels)
    times = frame_times(duration, fps)
    qpos = [_frame_qpos(p.trace, times, model.nq, np.asarray(qpos_adr)) for p in panels]
    mocap = [_frame_mocap(p.trace, times, model.nmocap) for p in panels]
    everything = [demo_world] + [p.trace.ee for p in panels] + [p.reference for p in panels
                                                                   if p.reference is not None]
    pts = np.concatenate(everything)
    span = float(np.max(np.ptp(pts, axis=0)))
    if demo_rotations is not None:   # the camera frames the drawn tool frames' axes too
        tips = np.asarray(demo_world)[:, None, :] + 2 * FRAME_FRACTION * span * np.swapaxes(demo_rotations, 1, 2)
        pts = np.concatenate([pts, tips.reshape(-1, 3)[::7]])
    fovy = float(model.vis.global_.fovy)
    if camera.orbit is None and camera.name != "auto":
        cam = fixed_camera(model, camera.name)
    else:
        if camera.orbit is None:
            fovy = AUTO_FOVY_DEG
        cam = task_camera(pts, base, normal, pw, ph, fovy, camera, _scene_points(model, qpos))
    data = mujoco.MjData(model)
    demo_d = decimate(np.asarray(demo_world), PATH_POINTS)
    layers = [StaticLayer(pw, ph) for _ in panels]
    axes_len = FRAME_FRACTION * max(span, 0.05)
    demo_frames = None
    if demo_rotations is not None:
        pick = np.unique(np.linspace(0, len(demo_world) - 1, DEMO_FRAMES).round().astype(int))
        demo_frames = (np.asarray(demo_world)[pick], np.asarray(demo_rotations)[pick])

    def frames() -> Iterable[np.ndarray]:
        bar = tqdm(total=len(times), desc="video", unit="frame", disable=not progress, leave=False)
        saved = float(model.vis.global_.fovy)
        model.vis.global_.fovy = fovy   # the free camera's field of view (render-only setting)
        shared = shared_renderer(model, pw, ph)
        r = shared if shared is not None else SceneRenderer(model, pw, ph)
        try:
            for j, t in enumerate(times):
                images = []
                for p, q, moved, layer in zip(panels, qpos, mocap, layers):
                    data.qpos[:] = q[j]
                    if moved is not None:
                        data.mocap_pos[:] = moved[j]
                    mujoco.mj_kinematics(model, data)
                    images.append(_panel_frame(r, data, cam, p, layer, demo_d, t, span, demo_frames, axes_len))
                bar.update(1)
                yield images[0] if len(images) == 1 else tile(images, cols)
        except BaseException:
            if shared is not None:          # an error or Ctrl-C inside a GL call: start afresh
                release_shared_renderer()
            raise
        finally:
            if shared is None:
                r.close()
            model.vis.global_.fovy = saved
            bar.close()

    return write_video(path, frames(), pw * cols, ph * rows, fps)


def _frame_uv(proj: Projector, origins: np.ndarray, rotations: np.ndarray, length: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of tool frames at origins (F, 3) with rotations (F, 3, 3): origins (F, 2), axis tips (F, 3, 2)."""
    tips = origins[:, None, :] + length * np.swapaxes(rotations, 1, 2)            # (F, 3 axes, 3)
    return proj(origins), proj(tips.reshape(-1, 3)).reshape(len(origins), 3, 2)


def _panel_frame(r: SceneRenderer, data: mujoco.MjData, cam: mujoco.MjvCamera, panel: Panel,
                 layer: StaticLayer, demo: np.ndarray, t: float, span: float,
                 demo_frames: tuple[np.ndarray, np.ndarray] | None = None, axes_len: float = 0.0) -> np.ndarray:
    """One panel's image at time t: the scene, the static layer (drawn on the first call), then
    the overlays that change (a pose task's live tool frame among them)."""
    ro = panel.trace
    image = r.render(data, cam)
    dt = float(ro.t[1] - ro.t[0])
    k = min(int(round(t / dt)), len(ro.ee) - 1)
    proj = Projector(r.scene, r.width, r.height)
    if not hasattr(layer, "mask"):
        field_uv = None if panel.reference is None else proj(decimate(panel.reference, PATH_POINTS))
        draw_static(layer.image, proj(demo), field_uv, panel.title)
        if demo_frames is not None:
            draw_frames(layer.image, *_frame_uv(proj, demo_frames[0], demo_frames[1], axes_len), 2)
        layer.freeze()
    layer.stamp(image)
    trace = decimate(ro.ee[:k + 1], PATH_POINTS)
    if len(trace) and not np.array_equal(trace[-1], ro.ee[k]):
        trace = np.vstack([trace, ro.ee[k]])
    window = ro.push_window_s
    push_uv = dot_uv = None
    if window is not None and ro.push_force is not None:
        k0 = int(np.searchsorted(ro.t, window[0] - 1e-9))
        if k >= k0:
            dot_uv = proj(ro.ee[k0][None])[0]
        if window[0] - 1e-9 <= t < window[1] + 0.1:
            head = ro.ee[k]   # at the tool (the pushed body's centre may be far from the path)
            force = np.asarray(ro.push_force, dtype=np.float64)
            vec = PUSH_ARROW_FRACTION * max(span, 0.05) * force / max(float(np.linalg.norm(force)), 1e-12)
            ends = proj(np.array([head - vec, head]))
            push_uv = (ends[0], ends[1])
    img = Image.fromarray(image)
    err = None if panel.reference is None else float(np.linalg.norm(ro.ee[k] - panel.reference[k]))
    goal = ro.goal_world if panel.goal_path is None else panel.goal_path[k]
    acted = ro.limiter_acted   # the limiter held the command within the last 50 ms
    held = acted is not None and bool(acted[max(0, k - int(round(0.05 / dt))):k + 1].any())
    draw_dynamic(img, proj(trace), proj(goal[None])[0], push_uv, dot_uv, FrameText(panel.title, t, err, held))
    if ro.ee_rot is not None:
        draw_frames(img, *_frame_uv(proj, ro.ee[k][None], ro.ee_rot[k][None], 2.0 * axes_len), 4)
    return np.asarray(img)

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
