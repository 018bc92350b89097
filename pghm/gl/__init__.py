"""OpenGL rendering shared by ``pghm render`` and the viewer: Gaussians as GL sprites.

The GL path reproduces the CPU splatter (``pghm.splat.render``) up to float rounding; see
docs/gl.md. Creating a context or renderer needs a current OpenGL 3.3 context; importing
this package does not touch GL.

    ctx = headless_context()
    with SpriteRenderer(ctx) as renderer:
        renderer.set_gaussians(means, scales, colors, opacities)
        image = renderer.render(camera, background=(1, 1, 1))  # image.rgb (H, W, 3)
    ctx.release()
"""

from pghm.gl.context import DriverInfo, driver_info, headless_context
from pghm.gl.sprites import FrameTimings, SpriteImage, SpriteRenderer

__all__ = ["DriverInfo", "FrameTimings", "SpriteImage", "SpriteRenderer", "driver_info", "headless_context"]
