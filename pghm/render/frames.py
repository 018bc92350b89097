"""Frame renderers: Gaussian arrays + camera -> float RGB image, through GL or the CPU splatter.

:class:`GLFrames` draws with the viewer's GL path (``pghm.gl.SpriteRenderer``) on a
headless EGL context; :class:`CPUFrames` with ``pghm.splat.render`` (the spec). The two
agree up to the 2e-3 GL/CPU tolerance; :func:`frame_renderer` picks one for a
:data:`Backend`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Literal

import numpy as np
import torch

from pghm.device import CPU
from pghm.errors import DisplayError, PghmError
from pghm.render.driver import GaussianArrays
from pghm.splat import Camera

Backend = Literal["auto", "gl", "cpu"]

GL_SIZE_LIMITS = ("GL_MAX_TEXTURE_SIZE", "GL_MAX_RENDERBUFFER_SIZE", "GL_MAX_VIEWPORT_DIMS")
"""The context limits an offscreen image of W x H must fit (each side)."""


class GLFrames:
    """Gaussian arrays -> float RGB through the GL sprite renderer on a headless EGL context.

    Set-up creates the context and renderer; :meth:`release` frees both.
    """

    def __init__(self) -> None:
        from pghm.gl import SpriteRenderer, driver_info, headless_context

        self.ctx = headless_context()
        self.renderer = SpriteRenderer(self.ctx)
        self.driver = str(driver_info(self.ctx))
        self._arrays: GaussianArrays | None = None

    def check_size(self, width: int, height: int) -> None:
        """PghmError, before anything is allocated, when W x H exceeds one of the context's GL_SIZE_LIMITS."""
        for name in GL_SIZE_LIMITS:
            limit = min(np.atleast_1d(self.ctx.info[name]))
            if max(width, height) > limit:
                raise PghmError(
                    f"--size {width}x{height} is beyond this OpenGL context's {name} of {limit}; "
                    "render smaller, or with --backend cpu"
                )

    def render(self, arrays: GaussianArrays, camera: Camera, background: tuple[float, float, float]) -> np.ndarray:
        """(H, W, 3) float32 image, row 0 at the top."""
        if arrays is not self._arrays:
            self.renderer.set_gaussians(arrays.means, arrays.scales, arrays.colors, arrays.opacities)
            self._arrays = arrays
        return self.renderer.render(camera, background).rgb

    def release(self) -> None:
        self.renderer.release()
        self.ctx.release()


class CPUFrames:
    """Gaussian arrays -> float RGB through ``pghm.splat.render`` on ``device``: the CPU splatter
    (the spec), or gsplat on CUDA."""

    def __init__(self, device: torch.device = CPU) -> None:
        self.device = device
        self.driver = "CPU splatter (pghm.splat)" if device.type == "cpu" else f"gsplat on {device}"

    def check_size(self, width: int, height: int) -> None:
        """Any size within the render job's pixel budget (checked there)."""

    def render(self, arrays: GaussianArrays, camera: Camera, background: tuple[float, float, float]) -> np.ndarray:
        """(H, W, 3) float32 image, row 0 at the top."""
        from pghm.splat import render

        out = render(
            torch.from_numpy(arrays.means).to(self.device),
            torch.from_numpy(arrays.scales).to(self.device),
            torch.from_numpy(arrays.colors).to(self.device),
            torch.from_numpy(arrays.opacities).to(self.device),
            camera,
            background=background,
        )
        return out.rgb.cpu().numpy()

    def release(self) -> None:
        """Nothing to free."""


@contextmanager
def frame_renderer(
    backend: Backend, log: Callable[[str], None] | None = None, device: torch.device = CPU
) -> Iterator[GLFrames | CPUFrames]:
    """A :class:`GLFrames` or :class:`CPUFrames` (splatting on ``device``), released on exit.

    "auto" is GL when a headless EGL context can be made, else the CPU splatter (``log``
    is told why in one line): same image either way, up to the 2e-3 GL/CPU tolerance.
    """
    if backend not in ("auto", "gl", "cpu"):
        raise PghmError(f"backend must be 'auto', 'gl' or 'cpu', got {backend!r}")
    if backend == "auto":
        try:
            frames = GLFrames()
        except DisplayError as error:
            if log is not None:
                log(f"no headless OpenGL ({str(error).splitlines()[0]}); rendering with the CPU splatter")
            frames = CPUFrames(device)
    else:
        frames = GLFrames() if backend == "gl" else CPUFrames(device)
    try:
        yield frames
    finally:
        frames.release()
