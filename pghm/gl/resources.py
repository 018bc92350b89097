"""GL helpers shared by the renderer and the GPU sort: programs and the texture layout.

Per-Gaussian data live in float textures, one texel per Gaussian per attribute, in rows of
``TEXTURE_WIDTH`` texels: Gaussian i is texel (i mod TEXTURE_WIDTH, i div TEXTURE_WIDTH).
Textures rather than vertex attributes let the draw visit Gaussians in any order (the depth
order is a separate small texture) without re-uploading their attributes.
"""

from __future__ import annotations

import moderngl
import numpy as np

import shaders
from pghm.errors import PghmError
from pghm.splat.spec import ALPHA_MAX, ALPHA_MIN, COV_DILATION, FRUSTUM_CLAMP, NEAR_PLANE

TEXTURE_WIDTH = 1024
"""Texels per row: OpenGL 3.3 guarantees textures at least this wide."""

MAX_GAUSSIANS = 1 << 24
"""Gaussian indices pass through float32 textures, exact below 2^24."""

SPEC_DEFINES: dict[str, int | float] = {
    "NEAR_PLANE": NEAR_PLANE,
    "COV_DILATION": COV_DILATION,
    "ALPHA_MAX": ALPHA_MAX,
    "ALPHA_MIN": ALPHA_MIN,
    "FRUSTUM_CLAMP": FRUSTUM_CLAMP,
    "TEXTURE_WIDTH": TEXTURE_WIDTH,
}
"""The ``#define`` lines every program of :mod:`pghm.gl` is compiled with: the CPU splatter's
constants (one definition, :mod:`pghm.splat.spec`) and the texture layout."""


def build_program(
    ctx: moderngl.Context,
    vertex: str,
    fragment: str,
    precision: shaders.Precision | None = None,
    defines: dict[str, int | float] | None = None,
) -> moderngl.Program:
    """A program from ``shaders/<vertex>.glsl`` and ``shaders/<fragment>.glsl`` with SPEC_DEFINES.

    ``precision`` ("float" or "double") is for shaders written with the ``real`` macro types
    (see :mod:`shaders`): it sets their ``#version`` and defines the types. ``defines`` adds
    variant switches (e.g. ``PGHM_POINTS``).
    """
    every = {**SPEC_DEFINES, **(defines or {})}
    return ctx.program(
        vertex_shader=shaders.source(vertex, every, precision),
        fragment_shader=shaders.source(fragment, every, precision),
    )


def texture_rows(count: int) -> int:
    """Rows of TEXTURE_WIDTH texels needed for ``count`` texels (at least 1)."""
    return max(1, -(-count // TEXTURE_WIDTH))


def float_texture(ctx: moderngl.Context, rows: int, components: int) -> moderngl.Texture:
    """A TEXTURE_WIDTH x rows float32 texture read only with texelFetch (nearest, no mipmaps)."""
    texture = ctx.texture((TEXTURE_WIDTH, rows), components, dtype="f4")
    texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return texture


def as_array(name: str, value: object, shape: tuple[int, ...], dtype: type = np.float32) -> np.ndarray:
    """``value`` (numpy array or torch tensor) as a C-contiguous ``dtype`` array of ``shape``.

    ``-1`` in ``shape`` matches any length. Raises PghmError naming ``name`` otherwise.
    """
    if hasattr(value, "detach"):  # torch.Tensor, without importing torch here
        value = value.detach().cpu().numpy()
    array = np.ascontiguousarray(value, dtype=dtype)
    if array.ndim != len(shape) or any(want not in (-1, got) for want, got in zip(shape, array.shape)):
        expected = "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
        raise PghmError(f"{name} must have shape {expected}, got {tuple(array.shape)}")
    return array
