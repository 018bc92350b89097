"""Screen box containing every sprite: the CPU bound on the vertex shader's quads.

Clearing the float target and compositing cost a full-screen pass each on llvmpipe
(~2-3 ms at 1280 x 720); the renderer restricts both to this box. Outside it no sprite
reaches, so the image there is exactly the background (alpha 0).

Bound. ``shaders/gaussian_sprite.vert.glsl`` places the corners of Gaussian i at
(u, v) + e (l00 w_x, l10 w_x + l11 w_y), |w_x|, |w_y| <= 1, with cov2d = L L^T and
e = sqrt(k) 1.001 + 1e-3, k = 2 ln(o / ALPHA_MIN). Since l00 = sqrt(a) and
|l10| + l11 <= sqrt(2 (l10^2 + l11^2)) = sqrt(2 c), the quad lies within
|x - u| <= e sqrt(a), |y - v| <= e sqrt(2 c); a and c (the diagonal of cov2d) are
computed here from the same float32 formulas, and the box gets one more pixel for the
shader's different rounding.

Points. Drawn as a GL point instead, Gaussian i needs the square of half side
e sqrt(max(a, c)) (the ellipse's bounding box is e sqrt(a) by e sqrt(c)); the largest such
half side decides whether the points fit the driver's largest point size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pghm.splat.spec import ALPHA_MIN, COV_DILATION, FRUSTUM_CLAMP, NEAR_PLANE

Box = tuple[int, int, int, int]
"""(x, y, width, height) in pixels, x from the left, y = image row (GL row of the target)."""


@dataclass(frozen=True)
class Extent:
    """Where the sprites of one camera reach.

    Attributes:
        box: the pixel box covering every quad.
        largest_point_half: the largest half side (pixels) of a point sprite's square.
    """

    box: Box
    largest_point_half: float


def sprite_extent(
    means: np.ndarray,
    scales: np.ndarray,
    opacities: np.ndarray,
    world_to_camera: np.ndarray,
    focal: tuple[float, float],
    principal: tuple[float, float],
    size: tuple[int, int],
) -> Extent | None:
    """The extent of the sprites of means (N, 3), scales (N,), opacities (N,).

    ``focal`` = (fx, fy), ``principal`` = (cx, cy), ``size`` = (W, H). None when no
    Gaussian is drawn (all culled, or all quads outside the image).
    """
    w2c = np.asarray(world_to_camera, np.float32)
    mx, my, mz = means.T  # 1-D column views: numpy is slow on rows of 3
    # t = R mu + T in float32, as the shader.
    tx, ty, tz = (w2c[r, 0] * mx + w2c[r, 1] * my + w2c[r, 2] * mz + w2c[r, 3] for r in range(3))
    drawn = (tz > np.float32(NEAR_PLANE)) & (opacities >= np.float32(ALPHA_MIN))
    if not drawn.any():
        return None
    # Culled Gaussians get k = 0 and a centre of NaN, which nanmin / nanmax skip.
    k = 2.0 * np.log(np.maximum(opacities, np.float32(ALPHA_MIN)) / np.float32(ALPHA_MIN))
    e = np.sqrt(k) * np.float32(1.001) + np.float32(1e-3)
    s2 = scales * scales
    depth = np.where(drawn, tz, np.float32(np.nan))
    low, high, point_halves = [], [], []
    for t, f, c, n, factor in ((tx, focal[0], principal[0], size[0], 1.0), (ty, focal[1], principal[1], size[1], 2.0)):
        f, c = np.float32(f), np.float32(c)
        ratio = t / depth
        limit = np.float32(FRUSTUM_CLAMP * n / (2.0 * f))
        j_diag = f / depth
        j_last = -f * np.clip(ratio, -limit, limit) / depth
        diagonal = s2 * (j_diag * j_diag + j_last * j_last) + np.float32(COV_DILATION)  # a (x), c (y)
        centre = f * ratio + c
        half = e * np.sqrt(np.float32(factor) * diagonal)
        point_halves.append(e * np.sqrt(diagonal))
        # The shader rounds the same float32 formulas (in another order): one pixel of slack.
        lowest, highest = float(np.nanmin(centre - half)), float(np.nanmax(centre + half))
        low.append(min(max(math.floor(lowest) - 1, 0), n))
        high.append(min(max(math.ceil(highest) + 1, 0), n))
    if high[0] <= low[0] or high[1] <= low[1]:
        return None
    # Culled Gaussians' halves are NaN too (their depth is), and nanmax skips them.
    largest_point_half = float(np.nanmax(np.maximum(*point_halves)))
    return Extent((low[0], low[1], high[0] - low[0], high[1] - low[1]), largest_point_half)


def grow(box: Box, pixels: int, size: tuple[int, int]) -> Box:
    """``box`` grown by ``pixels`` on every side, clipped to an image of ``size`` = (W, H)."""
    x0, y0 = max(box[0] - pixels, 0), max(box[1] - pixels, 0)
    x1, y1 = min(box[0] + box[2] + pixels, size[0]), min(box[1] + box[3] + pixels, size[1])
    return x0, y0, x1 - x0, y1 - y0
