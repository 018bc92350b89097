"""Headless OpenGL contexts and the driver they run on.

The GL paths need only OpenGL 3.3 core (instancing, float render targets and float
blending, texelFetch, integer ops in shaders). Offscreen contexts come from EGL, which
needs no display server; on a machine without a GPU, Mesa's llvmpipe provides one.
Nothing here runs at import time.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl

from pghm.errors import DisplayError

REQUIRED_GL_VERSION = 330
"""OpenGL 3.3 core, as moderngl's version code (major * 100 + minor * 10)."""

EGL_PACKAGES = "libegl1 libgl1-mesa-dri libegl-mesa0"
"""The Debian packages that provide EGL and Mesa's software rasteriser."""


@dataclass(frozen=True)
class DriverInfo:
    """What ``glGetString`` reports about the context's driver.

    Attributes:
        renderer: GL_RENDERER, e.g. ``llvmpipe (LLVM 15.0.6, 256 bits)``.
        version: GL_VERSION, e.g. ``4.5 (Core Profile) Mesa 22.3.6``.
        vendor: GL_VENDOR, e.g. ``Mesa``.
    """

    renderer: str
    version: str
    vendor: str

    def __str__(self) -> str:
        return f"{self.renderer}, OpenGL {self.version}"


def headless_context() -> moderngl.Context:
    """A standalone OpenGL >= 3.3 core context through EGL (no window, no display server).

    The caller owns it and ends it with ``ctx.release()``.

    Raises:
        DisplayError: EGL or a 3.3 core context is unavailable; the message names the fix.
    """
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=REQUIRED_GL_VERSION)
    except Exception as error:  # moderngl/glcontext raise plain Exception with the EGL reason
        raise DisplayError(
            f"cannot create a headless OpenGL 3.3 context through EGL ({error}); "
            f"install the system packages: apt-get install {EGL_PACKAGES}"
        ) from error
    if ctx.version_code < REQUIRED_GL_VERSION:
        version = ctx.info["GL_VERSION"]
        ctx.release()
        raise DisplayError(
            f"the EGL driver offers OpenGL {version}, but 3.3 core is required; "
            f"install Mesa: apt-get install {EGL_PACKAGES}"
        )
    return ctx


def driver_info(ctx: moderngl.Context) -> DriverInfo:
    """The renderer, version and vendor strings of ``ctx``'s driver."""
    info = ctx.info
    return DriverInfo(renderer=info["GL_RENDERER"], version=info["GL_VERSION"], vendor=info["GL_VENDOR"])
