"""MuJoCo's OpenGL backend, chosen before mujoco is imported: evaluate.py imports this first.

MuJoCo reads MUJOCO_GL once, when it is first imported. Unset, it picks GLFW, which needs a
display: on a Linux machine without one (a server, CI) this sets MUJOCO_GL=egl (Mesa's EGL renders
on the CPU there). A MUJOCO_GL that would make `import mujoco` itself fail (an unknown value, or
egl/osmesa without its library) would stop every evaluation, video or not: it becomes `disable`
and `PROBLEM` says why, so the flights still fly and only a video (`bfc.evaluation.video`) fails,
with one line. Nothing changes once mujoco has been imported.
"""

from __future__ import annotations

import ctypes.util
import os
import sys

_OFF = ("disable", "disabled", "off", "false", "0")
_LINUX = ("", "enable", "enabled", "on", "true", "1", "glfw", "glx", "egl", "osmesa")  # mujoco's gl_context
_LIBRARY = {"egl": "EGL", "osmesa": "OSMesa"}

PROBLEM: str | None = None  # why this process cannot render (None: it may)


def _loadable(name: str) -> bool:
    """Whether lib<name> loads: dlopen of its usual soname first (a millisecond), else the search
    that runs ldconfig (tens of milliseconds of start-up)."""
    try:
        ctypes.CDLL(f"lib{name}.so.1")
        return True
    except OSError:
        return ctypes.util.find_library(name) is not None


def choose_backend() -> str | None:
    """Set MUJOCO_GL where MuJoCo's own choice cannot work; return the backend in force."""
    global PROBLEM
    if "mujoco" in sys.modules or not sys.platform.startswith("linux"):
        return os.environ.get("MUJOCO_GL")
    if "MUJOCO_GL" not in os.environ and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        os.environ["MUJOCO_GL"] = "egl"
    given = os.environ.get("MUJOCO_GL", "")
    value = given.lower().strip()
    if value in _OFF:
        PROBLEM = f"MUJOCO_GL={given} turns rendering off"
    elif value not in _LINUX:
        PROBLEM = f"MUJOCO_GL={given} is not a backend MuJoCo knows"
    elif value in _LIBRARY and not _loadable(_LIBRARY[value]):
        PROBLEM = f"MUJOCO_GL={given} but lib{_LIBRARY[value]} is not installed"
    if PROBLEM is not None:
        os.environ["MUJOCO_GL"] = "disable"  # mujoco imports without any OpenGL backend
    return os.environ["MUJOCO_GL"]


choose_backend()
