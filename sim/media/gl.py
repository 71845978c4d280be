"""Choice of the OpenGL back-end for headless rendering, made lazily.

MuJoCo and dm_control read ``MUJOCO_GL`` once, at import, and open (dm_control: EGL) or load
(MuJoCo: the back-end's library) a GL back-end right there, so a bad value, a missing library or
a broken driver used to end ``import sim`` with a traceback, even for ``--help`` or a run without
video. ``sim`` calls :func:`select_backend` first thing: it sets the default back-end and has
both imported with rendering off whenever they are first imported (an import hook), so that
importing ``sim`` never needs a GL back-end and costs no MuJoCo import; ``MUJOCO_GL`` is put back
for ``sim.media.render``, which opens its contexts itself (dm_control's ``Physics.render`` picks its
back-end at its first call instead). A value the user set is
always respected. Before simulating a run whose video will be rendered, call
:func:`require_backend`: a missing or broken back-end is then a ``RenderError`` with one line
naming what to install or set, before any simulation.
"""

from __future__ import annotations

import ctypes.util
import importlib
import importlib.abc
import importlib.machinery
import os
import sys
import types
from collections.abc import Callable, Sequence
from typing import Any, cast

# the values sim.media.render opens a context with; MuJoCo's other names (glx, on, 1, ...) mean GLFW there
GLFW_NAMES: tuple[str, ...] = ("glfw", "glx", "1", "on", "true", "enable", "enabled")
OFFSCREEN: tuple[str, ...] = ("egl", "osmesa", *GLFW_NAMES)
DISABLED: tuple[str, ...] = ("disable", "disabled", "off", "false", "0")
INSTALL: dict[str, str] = {   # what to install, Debian/Ubuntu package names
    "egl": "install libegl1 (apt install libegl1 libgl1-mesa-dri)",
    "osmesa": "install libosmesa6 (apt install libosmesa6)",
}
_IMPORTED_WITHOUT_GL = ("mujoco", "dm_control._render")
_ready: set[str] = set()   # back-ends whose probe context opened in this process


def library_found(backend: str) -> bool:
    """Whether the shared library a back-end needs is installed (libEGL, libOSMesa or libglfw)."""
    name = {"egl": "EGL", "osmesa": "OSMesa", "glfw": "glfw"}.get(backend)
    return name is not None and ctypes.util.find_library(name) is not None


def select_backend() -> str:
    """Set ``MUJOCO_GL`` unless the user did (``egl`` by default, ``osmesa`` when libEGL is missing
    but libOSMesa is installed, with a note on stderr), and have MuJoCo and dm_control's renderer
    module imported with rendering off (``MUJOCO_GL=disable`` for those imports only) whenever they
    are first imported. Never raises for a GL problem, opens no GL context and imports neither.
    Returns the back-end in use (lower case)."""
    user = os.environ.get("MUJOCO_GL")
    if user:
        backend = user.lower().strip()
    else:
        backend = "egl"
        if not library_found("egl") and library_found("osmesa"):
            backend = "osmesa"
            print("sim: libEGL not found, rendering with OSMesa (slower)", file=sys.stderr)
        os.environ["MUJOCO_GL"] = backend
    _import_without_gl()
    return backend


def _import_without_gl() -> None:
    """Have MuJoCo and dm_control's renderer module imported with ``MUJOCO_GL=disable`` (then
    ``MUJOCO_GL`` restored), whenever something first imports them: the modules already imported
    are left as they are, and for the others an import hook (``_WithoutGl``) is put first on
    ``sys.meta_path``. Nothing is imported here, so ``import sim`` stays cheap."""
    todo = [name for name in _IMPORTED_WITHOUT_GL if name not in sys.modules]
    if todo and not any(isinstance(f, _WithoutGl) for f in sys.meta_path):
        sys.meta_path.insert(0, _WithoutGl())


class _WithoutGl(importlib.abc.MetaPathFinder):
    """Finds the modules of ``_IMPORTED_WITHOUT_GL`` through the other finders and runs their code
    with rendering off (``_QuietLoader``); every other module is left to the other finders."""

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: types.ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in _IMPORTED_WITHOUT_GL:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = _QuietLoader(spec.loader)
                return spec
        return None


class _QuietLoader(importlib.abc.Loader):
    """A module's own loader, its code run with ``MUJOCO_GL=disable``; dm_control's renderer module
    then gets the renderer that picks its back-end at first use (``_deferred_dm_control_renderer``)."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType | None:
        return cast("types.ModuleType | None", self._inner.create_module(spec))

    def exec_module(self, module: types.ModuleType) -> None:
        # as robots.nogl.rendering_off, which cannot be imported here: robots imports mujoco
        saved = os.environ.get("MUJOCO_GL")
        os.environ["MUJOCO_GL"] = "disable"
        try:
            self._inner.exec_module(module)
        finally:
            if saved is None:
                del os.environ["MUJOCO_GL"]
            else:
                os.environ["MUJOCO_GL"] = saved
        if module.__name__ == "dm_control._render" and (os.environ.get("MUJOCO_GL") or "").lower().strip() \
                not in DISABLED:
            module.Renderer = _deferred_dm_control_renderer(module)  # type: ignore[attr-defined]

    def __getattr__(self, name: str) -> Any:   # get_resource_reader, is_package, ... of the real loader
        return getattr(self._inner, name)


def _deferred_dm_control_renderer(render: Any) -> Callable[..., Any]:
    """dm_control's ``Renderer`` (used by ``Physics.render``), chosen at its first call from
    ``MUJOCO_GL`` as dm_control would have at import; then it replaces itself."""
    def renderer(*args: Any, **kwargs: Any) -> Any:
        problem = backend_problem()
        if problem:
            raise RuntimeError(problem)
        name = os.environ.get("MUJOCO_GL", "egl").lower().strip()
        for names, importer in getattr(render, "_ALL_RENDERERS", ()):
            if name in names:
                render.Renderer, render.BACKEND = importer(), names[0]
                render.USING_GPU = names[0] in ("egl", "glfw")
                return render.Renderer(*args, **kwargs)
        raise RuntimeError(f"MUJOCO_GL={name}: dm_control cannot render with it; set MUJOCO_GL=egl")

    return renderer


def backend_problem(backend: str | None = None) -> str | None:
    """What stops ``backend`` (default: ``MUJOCO_GL``) from rendering offscreen, found without
    opening a context: a value that renders nothing, an unknown value, a missing library, GLFW
    without a display. None when nothing is known to be wrong."""
    raw = (os.environ.get("MUJOCO_GL", "egl") if backend is None else backend).strip()
    name = raw.lower()
    if name in DISABLED:
        return (f"MUJOCO_GL={raw} turns rendering off; unset it or set MUJOCO_GL=egl to render videos "
                "(or run without videos)")
    if name not in OFFSCREEN:
        return (f"MUJOCO_GL={raw} is not an OpenGL back-end for offscreen rendering; set MUJOCO_GL=egl "
                "(or osmesa), or unset it")
    kind = "glfw" if name in GLFW_NAMES else name
    if kind != "glfw" and not library_found(kind):   # the glfw package carries its own library
        other = ", or unset MUJOCO_GL to render with EGL" if kind != "egl" else (
            ", or libosmesa6 and set MUJOCO_GL=osmesa")
        lib = {"egl": "libEGL", "osmesa": "libOSMesa"}[kind]
        return f"MUJOCO_GL={raw}: {lib} is not installed; {INSTALL[kind]}{other}"
    if kind == "glfw" and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return (f"MUJOCO_GL={raw} needs a display and DISPLAY is not set; unset MUJOCO_GL (or set "
                "MUJOCO_GL=egl) to render headless")
    return None


def require_backend() -> None:
    """Check that videos can be rendered with the back-end of ``MUJOCO_GL``: the static checks of
    ``backend_problem``, then a 1 x 1 context of that back-end opened and freed (once per
    process and back-end). Call it before simulating runs whose videos will be rendered.

    Raises
    ------
    sim.errors.RenderError
        One line naming the back-end, what went wrong and what to install or set.
    """
    from sim.errors import RenderError

    raw = os.environ.get("MUJOCO_GL", "egl").strip()
    name = raw.lower()
    if name in _ready:
        return
    problem = backend_problem(raw)
    if problem:
        raise RenderError(problem)
    kind = "glfw" if name in GLFW_NAMES else name
    try:
        _probe(kind)
    except Exception as e:  # noqa: BLE001  the back-ends raise ImportError, RuntimeError, OSError, GL errors
        first = (str(e).strip().splitlines() or [type(e).__name__])[0].split(". ")[0][:160]
        hint = {"egl": f"{INSTALL['egl']} with a working driver, or libosmesa6 and set MUJOCO_GL=osmesa",
                "osmesa": f"{INSTALL['osmesa']}, or unset MUJOCO_GL to render with EGL",
                "glfw": "unset MUJOCO_GL (or set MUJOCO_GL=egl) to render headless"}[kind]
        raise RenderError(f"MUJOCO_GL={raw}: cannot open an OpenGL context ({first}); {hint}") from None
    _ready.add(name)


def _probe(kind: str) -> None:
    """Open a 1 x 1 context of the back-end ``kind`` (egl, osmesa, glfw), make it current, free it;
    raise when any step fails (GLFW reports some failures only as warnings and a missing window)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if kind == "egl":
            from mujoco.egl import GLContext
        elif kind == "osmesa":
            from mujoco.osmesa import GLContext
        else:
            from mujoco.glfw import GLContext
        ctx = GLContext(1, 1)
        try:
            if not getattr(ctx, "_context", True):
                said = [str(w.message) for w in caught]
                raise RuntimeError(said[0] if said else "no context was created")
            ctx.make_current()
        finally:
            ctx.free()
