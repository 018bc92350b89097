"""The readable twin of the native kernel: spec steps 5-6 in plain PyTorch, differentiated by autograd.

Its fast partner is ``_rasterize.cpp`` (driven by :mod:`pghm.splat.native`); the tests hold
the two to each other and both to a brute-force float64 evaluation of the spec. It is
also the fallback when the native kernel cannot be built.

It never builds dense N x H x W tensors: it works on fragments, the (pixel, Gaussian)
pairs inside each Gaussian's footprint box, in five steps:

1. Enumerate the pixels of every visible Gaussian's footprint box (a per-pixel binning).
2. alpha = min(ALPHA_MAX, o exp(-d^T Q d / 2)) per fragment; keep those with alpha >= cutoff.
3. Sort fragments by (image, pixel, depth rank): each pixel's fragments become one
   contiguous segment, front to back.
4. Transmittance T_i = prod_{j<i} (1 - alpha_j) within each segment, as the exponential of
   a segmented exclusive cumulative sum of log(1 - alpha) in float64: exact to about 1e-12
   for any segment length, and T may fall far below float32's range in heavy overlap.
5. Scatter-add c alpha T and t_z alpha T into the pixels; add T_N times the background.
"""

from __future__ import annotations

import torch
from torch import Tensor

from pghm.splat._projection import Footprints
from pghm.splat._settings import SplatSettings
from pghm.splat.spec import ALPHA_MAX


def _box_pixels(footprints: Footprints) -> tuple[Tensor, Tensor, Tensor]:
    """Every pixel of every visible Gaussian's footprint box: (P,) flat Gaussian b N + n, column, row."""
    gaussian_ids = footprints.visible.reshape(-1).nonzero().squeeze(1)
    x0, x1, y0, y1 = footprints.bbox.reshape(-1, 4)[gaussian_ids].long().unbind(-1)
    box_width = x1 - x0 + 1
    sizes = box_width * (y1 - y0 + 1)
    gaussian = torch.repeat_interleave(gaussian_ids, sizes)
    position = torch.arange(gaussian.shape[0]) - torch.repeat_interleave(torch.cumsum(sizes, 0) - sizes, sizes)
    box_width = torch.repeat_interleave(box_width, sizes)
    column = torch.repeat_interleave(x0, sizes) + position % box_width
    row = torch.repeat_interleave(y0, sizes) + position // box_width
    return gaussian, column, row


def _segment_transmittance(alpha: Tensor, pixel: Tensor, num_pixels: int) -> tuple[Tensor, Tensor]:
    """T_i of each fragment (P,) and T_N of each pixel (num_pixels,), both float64.

    ``pixel`` (P,) is sorted, so each pixel's fragments are one contiguous, front-to-back segment.
    """
    log_keep = torch.log1p(-alpha.to(torch.float64))
    exclusive = torch.cumsum(log_keep, 0) - log_keep
    is_first = torch.ones_like(pixel, dtype=torch.bool)
    is_first[1:] = pixel[1:] != pixel[:-1]
    positions = torch.arange(pixel.shape[0])
    segment_first = torch.where(is_first, positions, torch.zeros_like(positions)).cummax(0).values
    transmittance = torch.exp(exclusive - exclusive[segment_first])
    final = torch.exp(torch.zeros(num_pixels, dtype=torch.float64).index_add(0, pixel, log_keep))
    return transmittance, final


def rasterize(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    depths: Tensor,
    background: Tensor,
    footprints: Footprints,
    width: int,
    height: int,
    settings: SplatSettings,
) -> tuple[Tensor, Tensor, Tensor]:
    """Composite B images: rgb (B, H, W, 3), alpha (B, H, W), depth (B, H, W) in the colors' dtype.

    Args:
        means2d: (B, N, 2) float64 screen means.
        conics: (B, N, 3) float64 conics (a, b, c).
        colors: (B, N, 3).
        opacities: (B, N).
        depths: (B, N) camera-space t_z in the working dtype (the composited depth).
        background: (3,) in the working dtype.
        footprints: boxes, visibility and depth order from :func:`pghm.splat._projection.footprints`.
        width, height: W, H.
        settings: the approximations in force.
    """
    batch, num_gaussians = opacities.shape
    dtype = colors.dtype
    num_pixels = batch * height * width

    # 1. Fragments: pixels of the footprint boxes.
    gaussian, column, row = _box_pixels(footprints)

    # 2. alpha per fragment. The offset d is formed in float64, then rounded (as the native kernel).
    means = means2d.reshape(-1, 2)[gaussian]
    dx = (column + 0.5 - means[:, 0]).to(dtype)
    dy = (row + 0.5 - means[:, 1]).to(dtype)
    a, b, c = conics.reshape(-1, 3)[gaussian].to(dtype).unbind(-1)
    raw_alpha = opacities.reshape(-1)[gaussian] * torch.exp(-0.5 * (a * dx * dx + 2 * b * dx * dy + c * dy * dy))
    keep = (raw_alpha >= settings.alpha_cutoff).detach()
    raw_alpha, gaussian, column, row = raw_alpha[keep], gaussian[keep], column[keep], row[keep]
    # min(ALPHA_MAX, .) passes no gradient where it clamps (3DGS).
    alpha = torch.where(raw_alpha < ALPHA_MAX, raw_alpha, torch.full_like(raw_alpha, ALPHA_MAX))

    # 3. Sort by (image, pixel, depth rank).
    rank = torch.empty(batch, num_gaussians, dtype=torch.long)
    rank.scatter_(1, footprints.order.long(), torch.arange(num_gaussians).expand(batch, -1).contiguous())
    pixel = ((gaussian // num_gaussians) * height + row) * width + column
    permutation = torch.argsort(pixel * num_gaussians + rank.reshape(-1)[gaussian])
    alpha, gaussian, pixel = alpha[permutation], gaussian[permutation], pixel[permutation]

    # 4. Transmittance; early termination drops every fragment behind T < stop.
    transmittance, final = _segment_transmittance(alpha, pixel, num_pixels)
    if settings.transmittance_stop > 0:
        alpha = torch.where(transmittance >= settings.transmittance_stop, alpha, torch.zeros_like(alpha))
        transmittance, final = _segment_transmittance(alpha, pixel, num_pixels)

    # 5. Scatter the weights c alpha T and t_z alpha T into the pixels.
    weight = alpha * transmittance.to(dtype)
    final = final.to(dtype)
    rgb = torch.zeros(num_pixels, 3, dtype=dtype).index_add(0, pixel, weight[:, None] * colors.reshape(-1, 3)[gaussian])
    rgb = rgb + final[:, None] * background
    depth = torch.zeros(num_pixels, dtype=dtype).index_add(0, pixel, weight * depths.reshape(-1)[gaussian])
    image = (batch, height, width)
    return rgb.reshape(*image, 3), (1 - final).reshape(image), depth.reshape(image)
