"""The headless OpenGL backend of MuJoCo's renderer.

``mujoco.Renderer`` takes its OpenGL context from the backend that the environment variable
``MUJOCO_GL`` names when MuJoCo's rendering module is first imported:

* ``egl``: EGL, with a GPU's driver (NVIDIA's ``libEGL_nvidia``) or, on a machine without one,
  Mesa's software rasteriser (llvmpipe; Debian: ``libegl-mesa0 libgl1-mesa-dri``);
* ``osmesa``: Mesa's off-screen software OpenGL (Debian: ``libosmesa6``);
* ``glfw`` / ``glx``: a window system (needs a display).

:func:`select` picks one: the environment's ``MUJOCO_GL`` where it is set, else EGL where
``libEGL`` and a vendor's EGL load, else OSMesa where ``libOSMesa`` loads.  :func:`activate` makes
``mujoco.Renderer`` use it (also where MuJoCo was imported before, as in a test process: its
context module is reloaded) and creates a 1 × 1 context to prove that it works.  Both raise
:class:`hlip_jax.presentation.render.RenderError` with one line naming what to set or install.
"""

from __future__ import annotations

import ctypes
import importlib
import os

from hlip_jax.presentation.render import RenderError

#: backend → the shared libraries it needs: of each group one must load (EGL: the dispatcher
#: and a vendor's implementation, Mesa's or NVIDIA's)
LIBRARIES = {"egl": (("libEGL.so.1", "libEGL.so"), ("libEGL_mesa.so.0", "libEGL_nvidia.so.0")),
             "osmesa": (("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so"),)}
#: backends that need no display, in the order :func:`select` tries them
HEADLESS = ("egl", "osmesa")
#: values of MUJOCO_GL that :func:`select` accepts
ALLOWED = HEADLESS + ("glfw", "glx")
#: what to do where none works
HINT = ("set MUJOCO_GL=egl (a GPU's driver, or Mesa's: apt-get install libegl-mesa0 "
        "libgl1-mesa-dri) or MUJOCO_GL=osmesa (apt-get install libosmesa6)")


def _loads(lib: str) -> bool:
    try:
        ctypes.CDLL(lib)
        return True
    except OSError:
        return False


def loadable(name: str) -> bool:
    """Whether backend ``name``'s libraries load: one of each group of :data:`LIBRARIES`."""
    groups = LIBRARIES.get(name, ())
    return bool(groups) and all(any(_loads(lib) for lib in group) for group in groups)


def select(environ=None) -> str:
    """The backend to render with: ``MUJOCO_GL`` of ``environ`` (default ``os.environ``) where
    set (one of :data:`ALLOWED`), else the first of :data:`HEADLESS` whose library loads."""
    environ = os.environ if environ is None else environ
    asked = environ.get("MUJOCO_GL", "").strip().lower()
    if asked:
        if asked not in ALLOWED:
            raise RenderError(f"MUJOCO_GL={asked!r}: allowed: {', '.join(ALLOWED)} "
                              "(egl and osmesa need no display)")
        return asked
    for name in HEADLESS:
        if loadable(name):
            return name
    raise RenderError("no OpenGL backend for headless rendering (neither libEGL nor "
                      f"libOSMesa loads): {HINT}")


def _module_of(name: str) -> str:
    """The MuJoCo module whose ``GLContext`` backend ``name`` uses."""
    return {"egl": "mujoco.egl", "osmesa": "mujoco.osmesa"}.get(name, "mujoco.glfw")


def _context_module():
    """MuJoCo's module that holds the ``GLContext`` ``mujoco.Renderer`` uses (its place moved
    in MuJoCo 4)."""
    try:
        return importlib.import_module("mujoco.rendering.classic.gl_context")
    except ImportError:
        return importlib.import_module("mujoco.gl_context")


def activate(name: str) -> None:
    """Make ``mujoco.Renderer`` create its OpenGL contexts with backend ``name`` (sets
    ``MUJOCO_GL``) and create one 1 × 1 context to check that it works; RenderError with the
    backend's complaint and :data:`HINT` otherwise."""
    os.environ["MUJOCO_GL"] = name
    try:
        gl_context = _context_module()
        current = getattr(gl_context, "GLContext", None)
        if getattr(current, "__module__", None) != _module_of(name):
            gl_context = importlib.reload(gl_context)
        ctx = gl_context.GLContext(1, 1)
        ctx.make_current()
        ctx.free()
    except Exception as err:      # ImportError, OSError, RuntimeError, the GL bindings' errors
        why = " ".join(str(err).split())[:200] or type(err).__name__
        raise RenderError(f"MUJOCO_GL={name}: no OpenGL context ({why}): {HINT}") from None
