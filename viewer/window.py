"""The platform layer: a glfw window, its OpenGL 3.3 core context and the imgui backends.

imgui-bundle's native backends (``imgui.backends.glfw_*`` and ``opengl3_*``) draw the UI on
the same context moderngl uses; no PyOpenGL is involved. ``imgui_bundle`` is imported
before ``glfw`` so that pyGLFW uses imgui-bundle's bundled GLFW library (one GLFW in the
process). Everything happens in :class:`Window`'s set-up and :meth:`Window.close`, nothing
at import time.
"""

from __future__ import annotations

import ctypes
import os
import sys

import moderngl
import numpy as np

from pghm.errors import DisplayError

GLSL_VERSION = "#version 330"
"""What imgui's OpenGL 3 backend compiles its shaders with (matches the 3.3 core context)."""


def display_problem() -> str | None:
    """Why no window can be opened here, or None if a display server is named (Linux)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY is not set)"
    return None


def _release_egl_thread() -> None:
    """Unbind any EGL context still current on this thread (a released headless context stays current).

    libglvnd lets a thread have a current EGL or GLX context, not both: after an EGL
    context (``pghm.gl.headless_context``, e.g. ``pghm render`` or a test) glXMakeCurrent
    fails with BadAccess, and Xlib's default handler exits the process.
    eglReleaseThread is a no-op when nothing is current.
    """
    try:
        egl = ctypes.CDLL("libEGL.so.1", mode=os.RTLD_NOLOAD)  # only if the process already uses EGL
    except OSError:
        return
    egl.eglReleaseThread()


class Window:
    """A resizable window with a moderngl context and imgui set up on it.

    Args:
        title: window title.
        size: (width, height) in screen pixels.

    Raises:
        DisplayError: no display server, or no OpenGL 3.3 core context on it.
    """

    def __init__(self, title: str, size: tuple[int, int]) -> None:
        import glfw
        from imgui_bundle import imgui  # before glfw: pyGLFW then loads imgui-bundle's GLFW

        self._glfw = glfw
        self._imgui = imgui
        problem = display_problem()
        if problem:
            raise DisplayError(problem)
        errors: list[str] = []
        glfw.ERROR_REPORTING = "ignore"  # failures are read from the callback and return values

        def collect(code: int, text: bytes | str) -> None:
            errors.append(text.decode() if isinstance(text, bytes) else str(text))

        glfw.set_error_callback(collect)
        if not glfw.init():
            reason = "; ".join(errors) or "glfw.init failed"
            raise DisplayError(f"cannot open the display {os.environ.get('DISPLAY', '')!r} ({reason})")
        _release_egl_thread()
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        self.handle = glfw.create_window(size[0], size[1], title, None, None)
        if not self.handle:
            glfw.terminate()
            raise DisplayError(f"cannot create an OpenGL 3.3 core window ({'; '.join(errors) or 'unknown reason'})")
        glfw.make_context_current(self.handle)
        glfw.swap_interval(0)  # the frame loop paces itself; vsync would hide frame times
        try:
            self.ctx = moderngl.create_context(require=330)
        except Exception as error:  # moderngl raises a plain Exception naming the GL problem
            glfw.destroy_window(self.handle)
            glfw.terminate()
            raise DisplayError(f"the window's OpenGL context is unusable ({error})") from error

        imgui.create_context()
        io = imgui.get_io()
        io.set_ini_filename("")  # no imgui.ini written next to the user's files
        address = ctypes.cast(self.handle, ctypes.c_void_p).value
        imgui.backends.glfw_init_for_opengl(address, True)
        imgui.backends.opengl3_init(GLSL_VERSION)
        self._size = self._query_size()

    # -------------------------------------------------------------------- per frame

    def should_close(self) -> bool:
        return bool(self._glfw.window_should_close(self.handle))

    def request_close(self) -> None:
        self._glfw.set_window_should_close(self.handle, True)

    def poll(self, wait_seconds: float = 0.0) -> None:
        """Process window events; with ``wait_seconds`` > 0, sleep until one arrives or the time passes."""
        if wait_seconds > 0:
            self._glfw.wait_events_timeout(wait_seconds)
        else:
            self._glfw.poll_events()

    def begin_ui(self) -> None:
        """Start an imgui frame (after :meth:`poll`); reads the framebuffer size for the frame."""
        self._size = self._query_size()
        self._imgui.backends.opengl3_new_frame()
        self._imgui.backends.glfw_new_frame()
        self._imgui.new_frame()

    def end_ui(self) -> None:
        """Draw the imgui frame over the window's framebuffer."""
        self._imgui.render()
        self.ctx.screen.use()
        width, height = self.framebuffer_size()
        self.ctx.viewport = (0, 0, width, height)
        self._imgui.backends.opengl3_render_draw_data(self._imgui.get_draw_data())

    def swap(self) -> None:
        self._glfw.swap_buffers(self.handle)

    def framebuffer_size(self) -> tuple[int, int]:
        """(W, H) of the drawable in pixels, as of this frame's :meth:`begin_ui` (a resize is an event)."""
        return self._size

    def _query_size(self) -> tuple[int, int]:
        # A round trip to the X server (~0.4 ms under load): once per frame, not per caller.
        width, height = self._glfw.get_framebuffer_size(self.handle)
        return int(width), int(height)

    def read_pixels(self, viewport: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """(H, W, 3) uint8 of the back buffer drawn so far (``viewport`` in GL pixels), row 0 at the top."""
        viewport = viewport or (0, 0, *self.framebuffer_size())
        data = self.ctx.screen.read(viewport=viewport, components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(viewport[3], viewport[2], 3)[::-1].copy()

    # ---------------------------------------------------------------------- teardown

    def close(self) -> None:
        """Shut imgui's backends down, release the context and destroy the window."""
        imgui, glfw = self._imgui, self._glfw
        imgui.backends.opengl3_shutdown()
        imgui.backends.glfw_shutdown()
        imgui.destroy_context()
        self.ctx.release()
        glfw.destroy_window(self.handle)
        glfw.terminate()
