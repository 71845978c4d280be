"""Choice of the OpenGL back-end for headless rendering, made before ``mujoco`` is imported.

MuJoCo and PyOpenGL read ``MUJOCO_GL`` / ``PYOPENGL_PLATFORM`` once, at import, so ``sim``
calls :func:`select_backend` first thing. A value the user set is always respected.
"""

from __future__ import annotations

import ctypes.util
import os
import sys


def library_found(backend: str) -> bool:
    """Whether the shared library a back-end needs is installed (libEGL, libOSMesa or libglfw)."""
    name = {"egl": "EGL", "osmesa": "OSMesa", "glfw": "glfw"}.get(backend)
    return name is not None and ctypes.util.find_library(name) is not None


def select_backend() -> str:
    """Set ``MUJOCO_GL`` unless the user did: ``egl`` by default, ``osmesa`` when libEGL is
    missing but libOSMesa is installed (with a note on stderr). Returns the back-end in use."""
    user = os.environ.get("MUJOCO_GL")
    if user:
        return user.lower().strip()
    backend = "egl"
    if not library_found("egl") and library_found("osmesa"):
        backend = "osmesa"
        print("sim: libEGL not found, rendering with OSMesa (slower)", file=sys.stderr)
    os.environ["MUJOCO_GL"] = backend
    return backend
