"""OpenGL set-up for pyrender: OSMesa (headless software rendering) unless another platform is asked for, and one
clear error when the platform's GL library is missing.

PyOpenGL picks its platform (`PYOPENGL_PLATFORM`) once, when `OpenGL` is first imported, so every module that needs
pyrender gets it from `import_pyrender()` here. Without an explicit `PYOPENGL_PLATFORM`, OSMesa is chosen, with or
without a display: it needs none, `scripts/install.sh` installs it, and it is the platform the face-id buffer is
tested on (pyrender's other offscreen path goes through pyglet and a hidden window, and multisampled framebuffers;
set `PYOPENGL_PLATFORM=egl` for a GPU). A missing GL library makes PyOpenGL
fail deep inside `import pyrender` (`'NoneType' object has no attribute 'glGetError'`); here it is checked first and
raised as `GLUnavailableError`, a one-sentence message naming the system package to install.
"""

from __future__ import annotations

import os
import sys
from types import ModuleType, TracebackType

#: Debian package and library file PyOpenGL loads, per platform.
GL_LIBRARIES = {
    "osmesa": ("libosmesa6", "libOSMesa.so"),
    "egl": ("libegl1", "libEGL.so"),
    "glx": ("libgl1", "libGL.so"),
}


class GLUnavailableError(RuntimeError):
    """The OpenGL library of the selected platform cannot be loaded (a system package is missing)."""


def select_platform() -> str:
    """Choose OSMesa unless `PYOPENGL_PLATFORM` names another platform; returns the platform PyOpenGL will use."""
    if not os.environ.get("PYOPENGL_PLATFORM"):
        os.environ["PYOPENGL_PLATFORM"] = "osmesa"
    return os.environ["PYOPENGL_PLATFORM"]


def check_gl() -> None:
    """Select the platform and load its GL library; raise `GLUnavailableError` naming the package if it is missing."""
    platform_name = select_platform()
    from OpenGL import platform  # loads the platform's library lazily, returning None when it is absent

    if platform.PLATFORM.GL is None:
        _print_without_traceback_if_uncaught()
        raise GLUnavailableError(missing_library_message(platform_name))


def missing_library_message(platform_name: str) -> str:
    """One sentence: which GL library the platform could not load and which system package provides it."""
    if platform_name not in GL_LIBRARIES:
        return f"rendering needs OpenGL, but PyOpenGL platform {platform_name} cannot load its GL library"
    package, library = GL_LIBRARIES[platform_name]
    setup = " or run `bash scripts/install.sh`" if platform_name == "osmesa" else ""
    return (f"rendering needs OpenGL, but {library} (PyOpenGL platform {platform_name}) cannot be loaded: install the "
            f"system package {package} (`apt-get install {package}`{setup})")


def import_pyrender() -> ModuleType:
    """`pyrender`, imported after `check_gl()`."""
    check_gl()
    import pyrender

    return pyrender


def _print_without_traceback_if_uncaught() -> None:
    """Let an uncaught `GLUnavailableError` end the program with its one-line message (exit code 1), not a traceback.

    The error is usually raised while a command's modules are imported, before its own error handling runs.
    """
    previous = sys.excepthook
    if getattr(previous, "prints_gl_errors", False):
        return

    def hook(kind: type[BaseException], error: BaseException, tb: TracebackType | None) -> None:
        if isinstance(error, GLUnavailableError):
            print(f"error: {error}", file=sys.stderr)
        else:
            previous(kind, error, tb)

    hook.prints_gl_errors = True  # type: ignore[attr-defined]
    sys.excepthook = hook
