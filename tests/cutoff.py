"""How far a float32 GL image may lie from the float64 splatting spec, pixel by pixel.

Two thresholds decide whether a (pixel, Gaussian) pair composites: alpha >= ALPHA_MIN and the
Gaussian's depth t_z > NEAR_PLANE. A pair whose alpha (or depth) lies within one side's relative
rounding of a threshold may be kept by one side and dropped by the other: such a flip changes its
pixel by alpha T |c - behind| <= alpha (T <= 1, colours and alpha in [0, 1]). Every other pair
differs only by the rounding of alpha and of the blend, which the project's bar ``MAX_ERROR``
holds. So each pixel may differ by at most

    allowance(p) = MAX_ERROR + sum of alpha (1 + band) over p's pairs within ``band`` of a threshold,

which is MAX_ERROR on all but a few rim pixels. It does not depend on the CPU, the thread count or
llvmpipe's vector width, only on the scene; a wrong footprint or a wrong order still shows up as
errors above MAX_ERROR on pixels whose allowance is MAX_ERROR.

Written from the spec (the docstring of :mod:`pghm.splat`) in float64 numpy, sharing no code with
either renderer.
"""

from __future__ import annotations

import numpy as np

from pghm.splat.spec import ALPHA_MAX, ALPHA_MIN, COV_DILATION, FRUSTUM_CLAMP, NEAR_PLANE

MAX_ERROR = 2e-3
"""The project's GL-vs-CPU bar for a pixel with no pair at a threshold. A relative error e of every
alpha moves a pixel by at most e sum(alpha T |c - behind|) <= e, so it holds the float projection's
1.2e-3 (see BAND) and the double projection's ~3e-6, plus the blend's float32 rounding (~1e-6)."""

MEAN_ERROR = 1e-4
"""The bar on the mean error over an image (flips are a few rim pixels out of thousands)."""

BAND = {"double": 1e-4, "float": 1e-2}
"""Relative rounding of a side's alpha at the cut-off, by the GL projection's precision, with margin.

alpha = o exp(-q / 2), q = d^T Q d, so a relative error e of alpha is an error 2 e of q.
* double: the offset d is rounded to float32 once and q is evaluated in float32 (a few ulp,
  ~3e-7 relative); at the cut-off q <= 2 ln(255 ALPHA_MAX) = 11.05, so q is off by ~4e-6 and
  alpha by ~2e-6, plus llvmpipe's float exp (~1e-6): 1e-4 is a 30x margin.
* float: the screen mean u is known to ~2e-4 px (a float32 u of up to 1280 px, three roundings);
  q moves by 2 sqrt(q lambda_max(Q)) du <= 2 sqrt(11.05 / COV_DILATION) 2e-4 = 2.4e-3, alpha by
  1.2e-3 relative: 1e-2 is an 8x margin.
The same relative band covers the near plane (t_z against NEAR_PLANE), which is evaluated with the
same precision as the projection."""

CHUNK = 1 << 21
"""Pairs evaluated at once (bounds the memory of a scene whose footprints cover the image)."""


def flip_allowance(means, scales, opacities, cam, band: float) -> np.ndarray:
    """(H, W) float64 allowance(p) for the scene (means (N, 3), scales (N,), opacities (N,)) seen by ``cam``.

    ``cam`` has fx, fy, cx, cy, width, height and a (4, 4) world_to_camera (OpenCV axes).
    """
    means = np.asarray(means, np.float64).reshape(-1, 3)
    scales, opacities = (np.asarray(a, np.float64).reshape(-1) for a in (scales, opacities))
    w2c = np.asarray(cam.world_to_camera, np.float64)
    t = means @ w2c[:3, :3].T + w2c[:3, 3]
    x, y, z = t.T
    at_near_plane = np.abs(z - NEAR_PLANE) <= band * NEAR_PLANE
    # Gaussians behind the near plane on both sides, or that never reach the cut-off, add nothing.
    keep = ((z > NEAR_PLANE) | at_near_plane) & (opacities * (1 + band) >= ALPHA_MIN)
    x, y, z, s, o, near = x[keep], y[keep], z[keep], scales[keep], opacities[keep], at_near_plane[keep]
    u = cam.fx * x / z + cam.cx
    v = cam.fy * y / z + cam.cy
    lim_x = FRUSTUM_CLAMP * cam.width / (2 * cam.fx)
    lim_y = FRUSTUM_CLAMP * cam.height / (2 * cam.fy)
    rx, ry = np.clip(x / z, -lim_x, lim_x), np.clip(y / z, -lim_y, lim_y)
    gx, gy = cam.fx / z, cam.fy / z
    # cov2d = s^2 J J^T + COV_DILATION I, J = [[gx, 0, -gx rx], [0, gy, -gy ry]].
    s_xx = s**2 * gx**2 * (1 + rx**2) + COV_DILATION
    s_xy = s**2 * gx * gy * rx * ry
    s_yy = s**2 * gy**2 * (1 + ry**2) + COV_DILATION
    det = s_xx * s_yy - s_xy**2
    a, b, c = s_yy / det, -s_xy / det, s_xx / det
    # Every pixel where the pair's alpha can reach ALPHA_MIN / (1 + band): q <= q_max.
    q_max = 2 * np.log(o * (1 + band) / ALPHA_MIN)
    half_x, half_y = np.sqrt(q_max * s_xx), np.sqrt(q_max * s_yy)
    x0 = np.clip(np.floor(u - half_x - 0.5), 0, cam.width - 1).astype(np.int64)
    x1 = np.clip(np.ceil(u + half_x - 0.5), 0, cam.width - 1).astype(np.int64)
    y0 = np.clip(np.floor(v - half_y - 0.5), 0, cam.height - 1).astype(np.int64)
    y1 = np.clip(np.ceil(v + half_y - 0.5), 0, cam.height - 1).astype(np.int64)
    inside = (u + half_x >= -0.5) & (u - half_x <= cam.width + 0.5) & (v + half_y >= -0.5) & (v - half_y <= cam.height + 0.5)
    widths, sizes = x1 - x0 + 1, (x1 - x0 + 1) * (y1 - y0 + 1) * inside

    allowance = np.zeros(cam.height * cam.width)
    ends = np.cumsum(sizes)
    first = 0
    while first < len(sizes):
        last = max(first + 1, int(np.searchsorted(ends, ends[first] - sizes[first] + CHUNK, side="right")))
        ids = np.repeat(np.arange(first, last), sizes[first:last])
        offset = np.arange(len(ids)) - np.repeat(np.cumsum(sizes[first:last]) - sizes[first:last], sizes[first:last])
        col = x0[ids] + offset % widths[ids]
        row = y0[ids] + offset // widths[ids]
        dx, dy = col + 0.5 - u[ids], row + 0.5 - v[ids]
        alpha = np.minimum(ALPHA_MAX, o[ids] * np.exp(-0.5 * (a[ids] * dx**2 + 2 * b[ids] * dx * dy + c[ids] * dy**2)))
        at_cutoff = np.abs(alpha - ALPHA_MIN) <= band * ALPHA_MIN
        flips = (at_cutoff | (near[ids] & (alpha >= ALPHA_MIN / (1 + band)))) & (alpha * (1 + band) >= ALPHA_MIN)
        np.add.at(allowance, row[flips] * cam.width + col[flips], np.minimum(1.0, alpha[flips] * (1 + band)))
        first = last
    return MAX_ERROR + allowance.reshape(cam.height, cam.width)


def within_allowance(error: np.ndarray, allowance: np.ndarray) -> dict[str, float]:
    """Summary of ``error`` ((H, W) or (H, W, C)) against the (H, W) ``allowance``: what an assertion reports."""
    worst = error.reshape(*allowance.shape, -1).max(-1)
    return {
        "max": float(worst.max()),
        "mean": float(error.mean()),
        "over_allowance": int((worst > allowance).sum()),
        "over_max_error": int((worst > MAX_ERROR).sum()),
        "pixels_at_a_threshold": int((allowance > MAX_ERROR).sum()),
    }
