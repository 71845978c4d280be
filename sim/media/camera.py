"""Where the video camera stands: a view chosen from the task, a user's choice, and projection to pixels.

``task_camera`` looks at the path from the side of the task plane's normal that faces away from
the robot (for 3-D paths the normal is the direction in which the path is thinnest), tilted
``TILT_DEG`` from the normal towards the side of the arm (across the vertical plane through the
base and the path, turned ``OUTWARD_DEG`` outwards): the arm, which reaches the path from the
base through that plane, is then seen in profile and rises away from the path in the image
instead of lying on it. The distance makes the path
span ``PATH_FRACTION`` of the frame's width (or 80% of its height, whichever is tighter), and keeps
the scene's bodies (the whole arm over the run, the objects) within ``SCENE_FRACTION`` of it.
``CameraSpec`` is the ``--camera`` option: ``auto``, a camera of the model by name, or
``azimuth,elevation,distance`` (degrees, degrees, metres) around the path's centre.
``project`` maps world points to pixel coordinates of the camera of a rendered scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

TILT_DEG = 55.0
OUTWARD_DEG = 65.0
PATH_FRACTION = 0.5
SCENE_FRACTION = 0.7


@dataclass(frozen=True)
class CameraSpec:
    """A parsed ``--camera``: ``name`` ("auto" or a model camera) or ``orbit`` (azimuth deg,
    elevation deg, distance m) around the path's centre."""

    name: str = "auto"
    orbit: tuple[float, float, float] | None = None

    @classmethod
    def parse(cls, text: str) -> CameraSpec:
        """'auto', a camera name, or 'AZ,EL,DIST'; raises ValueError with a one-line reason."""
        text = text.strip()
        if not text:
            raise ValueError("--camera needs a name or AZIMUTH,ELEVATION,DISTANCE")
        if "," in text:
            try:
                az, el, dist = (float(v) for v in text.split(","))
            except ValueError:
                raise ValueError(f"expected AZIMUTH,ELEVATION,DISTANCE (three numbers), got '{text[:40]}'") from None
            if not all(math.isfinite(v) for v in (az, el, dist)):
                raise ValueError(f"camera numbers must be finite, got '{text[:40]}'")
            if not -90.0 <= el <= 90.0:
                raise ValueError(f"camera elevation must be in [-90, 90] degrees, got {el:g}")
            if not 0.01 <= dist <= 100.0:
                raise ValueError(f"camera distance must be in [0.01, 100] m, got {dist:g}")
            return cls(name="orbit", orbit=(az, el, dist))
        return cls(name=text)

    def check(self, model: mujoco.MjModel) -> None:
        """A named camera must exist in ``model``; raises ValueError naming the known ones."""
        if self.orbit is not None or self.name == "auto":
            return
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, self.name) < 0:
            known = [model.camera(i).name for i in range(model.ncam)]
            raise ValueError(f"unknown camera '{self.name}'; use auto, AZIMUTH,ELEVATION,DISTANCE"
                             + (f" or one of: {', '.join(known)}" if known else ""))


def thin_normal(points: np.ndarray) -> np.ndarray:
    """Unit direction, shape (3,), in which points (K, 3) spread least (their plane's normal)."""
    centred = points - points.mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return vt[-1] / np.linalg.norm(vt[-1])


def task_camera(points: np.ndarray, base: np.ndarray, normal: np.ndarray | None, width: int, height: int,
                fovy_deg: float = 45.0, spec: CameraSpec = CameraSpec(),
                scene_points: np.ndarray | None = None) -> mujoco.MjvCamera:
    """The free camera of ``spec`` (``auto`` or an orbit) for a path through points, shape (K, 3)
    (world, m), of an arm whose base is at ``base``, shape (3,); ``normal`` (3,) is the task
    plane's (None: from the points). See the module docstring. ``fovy_deg`` is the vertical field
    of view it will be rendered with; ``width`` / ``height`` the frame's aspect; ``scene_points``
    (M, 3), world, what else must be in the frame (the arm's bodies over the run, the objects)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = pts.min(0), pts.max(0)
    centre = (lo + hi) / 2
    if spec.orbit is None and spec.name != "auto":
        raise ValueError(f"camera '{spec.name}' is a model camera: use fixed_camera")
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = centre
    if spec.orbit is not None:
        cam.azimuth, cam.elevation, cam.distance = spec.orbit
        return cam
    n = thin_normal(pts) if normal is None or np.ptp(pts, axis=0).max() == 0 else np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    away = centre - np.asarray(base, dtype=np.float64)        # from the base towards the path
    if n[2] < 0 or (abs(n[2]) < 0.3 and float(n @ away) < 0):
        n = -n                                                 # look from above, or from the far side
    outward = away - (away @ n) * n                            # in the plane, away from the base
    if np.linalg.norm(outward) < 1e-6:
        outward = np.cross(n, [0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    outward /= np.linalg.norm(outward)
    across = np.cross(outward, n)                               # in the plane, across the arm
    beta, tilt = math.radians(OUTWARD_DEG), math.radians(TILT_DEG)
    side = math.cos(beta) * across + math.sin(beta) * outward
    view = math.cos(tilt) * n + math.sin(tilt) * side         # from the path to the camera
    forward = -view / np.linalg.norm(view)
    cam.azimuth = math.degrees(math.atan2(forward[1], forward[0]))
    cam.elevation = math.degrees(math.asin(np.clip(forward[2], -1.0, 1.0)))
    cam.elevation = min(cam.elevation, -5.0) if n[2] > 0.3 else cam.elevation
    # the path's extent across and along the image (orthographic estimate) fixes the distance
    fwd = _forward(cam.azimuth, cam.elevation)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right = right / np.linalg.norm(right) if np.linalg.norm(right) > 1e-9 else np.array([0.0, 1.0, 0.0])
    up = np.cross(right, fwd)
    wide = float(np.ptp(pts @ right)) or 0.1
    tall = float(np.ptp(pts @ up)) or 0.1
    half_h = math.tan(math.radians(fovy_deg) / 2)
    half_w = half_h * width / height
    cam.distance = max(wide / (2 * PATH_FRACTION * half_w), tall / (2 * 0.8 * half_h), 0.05)
    if scene_points is not None and len(scene_points):   # the whole scene in the frame, around the path
        # a point at rel from the centre is at depth D + rel . fwd: |rel . right| / depth <= fraction x half_w
        rel = np.asarray(scene_points, dtype=np.float64).reshape(-1, 3) - centre
        cam.distance = max(cam.distance, float(np.max(np.abs(rel @ right) / (SCENE_FRACTION * half_w) - rel @ fwd)),
                           float(np.max(np.abs(rel @ up) / (SCENE_FRACTION * half_h) - rel @ fwd)))
    return cam


def fixed_camera(model: mujoco.MjModel, name: str) -> mujoco.MjvCamera:
    """A camera that renders the model's camera ``name``."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
    cam.fixedcamid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    return cam


def _forward(azimuth: float, elevation: float) -> np.ndarray:
    """MuJoCo's free-camera viewing direction, shape (3,)."""
    a, e = math.radians(azimuth), math.radians(elevation)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def project(scene: mujoco.MjvScene, points: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixel coordinates (u right, v down), shape (K, 2), of world points (K, 3) in the image that
    ``mjr_render`` makes of ``scene`` (after ``mjv_updateScene``) in a width x height viewport.
    Points behind the camera get NaN. To project several point sets of one frame, make one
    ``Projector`` instead."""
    return Projector(scene, width, height)(points)


class Projector:
    r"""The projection of world points to pixels for the camera of ``scene`` (after
    ``mjv_updateScene``) in a ``width`` x ``height`` viewport, set up once per frame.

    With the OpenGL camera at p looking along e_f, up e_u, right e_r = e_f x e_u, a world point x
    has camera coordinates (x_r, x_u, x_f) = (e_r, e_u, e_f) . (x - p) and lies at pixel

    .. math:: u = \left(\frac{n x_r}{x_f} - (c - w)\right) \frac{W}{2 w}, \qquad
              v = \left(t - \frac{n x_u}{x_f}\right) \frac{H}{t - b}

    with n, c, t, b the frustum's near distance, centre, top and bottom and w its half width (from
    the aspect W / H where the frustum gives none). Points with x_f <= 0 (behind) get NaN.
    """

    def __init__(self, scene: mujoco.MjvScene, width: int, height: int) -> None:
        glcam = mujoco.mjv_averageCamera(scene.camera[0], scene.camera[1])
        f, u = (np.asarray(v, dtype=np.float64).tolist() for v in (glcam.forward, glcam.up))
        right = [f[1] * u[2] - f[2] * u[1], f[2] * u[0] - f[0] * u[2], f[0] * u[1] - f[1] * u[0]]
        self.pos = np.array(glcam.pos, dtype=np.float64)                          # (3,)
        self.basis = np.array([right, u, f], dtype=np.float64).T                  # (3, 3): r, u, f
        near, bottom, top = glcam.frustum_near, glcam.frustum_bottom, glcam.frustum_top
        half_w = glcam.frustum_width if glcam.frustum_width > 0 else 0.5 * (top - bottom) * width / height
        # u = a_u x / z + b_u, v = a_v y / z + b_v with x, y, z the point in camera coordinates
        self._a = np.array([near / (2 * half_w) * width, -near / (top - bottom) * height])
        self._b = np.array([-(glcam.frustum_center - half_w) / (2 * half_w) * width, top / (top - bottom) * height])

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Pixels (u, v), shape (K, 2), of world points, shape (K, 3); NaN behind the camera."""
        cam = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.pos) @ self.basis   # (K, 3)
        z = cam[:, 2:]
        with np.errstate(divide="ignore", invalid="ignore"):
            out = cam[:, :2] / z * self._a + self._b
        out[z[:, 0] <= 1e-9] = np.nan
        return out
