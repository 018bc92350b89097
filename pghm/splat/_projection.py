"""Steps 2-5 of the spec (see :mod:`pghm.splat`), shared by both rasterisers.

Camera space, screen means and conics are plain differentiable torch, so autograd carries
the rasteriser's gradients on to the means, scales and the camera pose. Footprints (the
pixel box each Gaussian may touch) and the depth order carry no gradient.

Everything per Gaussian is computed in float64 whatever the working dtype: a float32 u at
512 px is only known to 3e-5 px, which for a sub-pixel Gaussian alone moves alpha by more
than the 1e-5 the renderer is held to. Per-Gaussian work is O(N), so this costs nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from pghm.splat.spec import COV_DILATION, FRUSTUM_CLAMP, NEAR_PLANE

if TYPE_CHECKING:
    from pghm.splat._settings import SplatSettings

FOOTPRINT_MARGIN = 1e-4
"""Relative slack on a footprint's squared radius, so rounding never puts a pixel that the
float32 alpha test accepts outside the pixels enumerated for its Gaussian; the alpha test,
not the box, decides."""


@dataclass(frozen=True)
class Projection:
    """Each Gaussian on each image's screen (differentiable).

    Attributes:
        means2d: (B, N, 2) float64 screen means (u, v) in pixels.
        conics: (B, N, 3) float64 (a, b, c), the conic Q = [[a, b], [b, c]] = inverse(cov2d).
        covariances: (B, N, 3) float64 (s_xx, s_xy, s_yy) of cov2d.
        depths: (B, N) float64 camera-space depth t_z (the sort key and the depth that is composited).
    """

    means2d: Tensor
    conics: Tensor
    covariances: Tensor
    depths: Tensor


@dataclass(frozen=True)
class Footprints:
    """Which pixels each Gaussian may touch, and in which order Gaussians composite (no gradients).

    Attributes:
        bbox: (B, N, 4) int32 inclusive pixel ranges (x0, x1, y0, y1), clipped to the image,
            holding every pixel whose alpha can reach the cut-off; zeros for invisible Gaussians.
        visible: (B, N) bool, in front of the near plane with a footprint that meets the image.
        order: (B, N) int32; per image the visible Gaussians front to back (stable), then the rest.
        counts: (B,) int64 number of visible Gaussians per image.
        radius2: (B, N) float64 k, padded: alpha >= cutoff where d^T Q d <= k (0 for invisible ones).
    """

    bbox: Tensor
    visible: Tensor
    order: Tensor
    counts: Tensor
    radius2: Tensor


def to_camera(means: Tensor, world_to_camera: Tensor) -> Tensor:
    """(B, N, 3) float64 camera-space means t = R mu + T from means (B, N, 3) and poses (B, 4, 4)."""
    pose = world_to_camera.to(torch.float64)
    # t[b, n, i] = sum_k R[b, i, k] mu[b, n, k] + T[b, i]
    return means.to(torch.float64) @ pose[:, :3, :3].transpose(-1, -2) + pose[:, None, :3, 3]


def project(means_cam: Tensor, scales: Tensor, intrinsics: Tensor, width: int, height: int) -> Projection:
    """Screen means, covariances and conics of isotropic Gaussians (spec steps 3-4).

    Args:
        means_cam: (B, N, 3) float64 camera-space means t.
        scales: (B, N) isotropic world standard deviations s.
        intrinsics: (B, 4) float64 [fx, fy, cx, cy].
        width, height: image size W, H in pixels (they set the frustum clamp).
    """
    x, y, depth = means_cam.unbind(-1)
    fx, fy, cx, cy = intrinsics.to(torch.float64).unsqueeze(-1).unbind(-2)  # (B, 1) each
    # Dropped Gaussians (t_z <= NEAR_PLANE) get a harmless depth here, so nothing below is
    # inf or NaN; they never reach the rasteriser, so their gradients stay exactly zero.
    z = torch.where(depth > NEAR_PLANE, depth, torch.ones_like(depth))
    u = fx * x / z + cx
    v = fy * y / z + cy
    # x' / t_z and y' / t_z: the clamp enters J only, never the mean.
    ratio_x = torch.clamp(x / z, -FRUSTUM_CLAMP * width / (2 * fx), FRUSTUM_CLAMP * width / (2 * fx))
    ratio_y = torch.clamp(y / z, -FRUSTUM_CLAMP * height / (2 * fy), FRUSTUM_CLAMP * height / (2 * fy))
    # With J = [[gx, 0, -gx ratio_x], [0, gy, -gy ratio_y]], gx = fx / t_z, gy = fy / t_z:
    # cov2d = s^2 J J^T + COV_DILATION I.
    variance = scales.to(torch.float64).square()
    gx, gy = fx / z, fy / z
    s_xx = variance * gx.square() * (1 + ratio_x.square()) + COV_DILATION
    s_xy = variance * gx * gy * ratio_x * ratio_y
    s_yy = variance * gy.square() * (1 + ratio_y.square()) + COV_DILATION
    determinant = s_xx * s_yy - s_xy.square()  # >= COV_DILATION^2 > 0
    conics = torch.stack([s_yy / determinant, -s_xy / determinant, s_xx / determinant], dim=-1)
    return Projection(
        means2d=torch.stack([u, v], dim=-1),
        conics=conics,
        covariances=torch.stack([s_xx, s_xy, s_yy], dim=-1),
        depths=depth,
    )


def squared_footprint_radius(opacities: Tensor, alpha_cutoff: float) -> Tensor:
    """k = 2 ln(o / cutoff), padded by FOOTPRINT_MARGIN: o exp(-q / 2) >= cutoff  <=>  q <= 2 ln(o / cutoff).

    Negative (or NaN) where the Gaussian can never reach the cut-off. Same shape as ``opacities``.
    """
    k = 2 * torch.log(opacities.to(torch.float64) / alpha_cutoff)
    return k * (1 + FOOTPRINT_MARGIN) + FOOTPRINT_MARGIN


@torch.no_grad()
def footprints(
    projection: Projection, opacities: Tensor, width: int, height: int, settings: SplatSettings
) -> Footprints:
    """Culling, footprint boxes and the front-to-back order (spec steps 2, 5 and 6)."""
    u, v = projection.means2d.unbind(-1)
    s_xx, s_xy, s_yy = projection.covariances.unbind(-1)
    k = squared_footprint_radius(opacities.detach(), settings.alpha_cutoff)
    radius2 = k.clamp(min=0)
    # The ellipse d^T Q d <= k, Q = cov2d^-1, spans exactly |dx| <= sqrt(k s_xx), |dy| <= sqrt(k s_yy).
    half_x, half_y = torch.sqrt(radius2 * s_xx), torch.sqrt(radius2 * s_yy)
    # Pixel j has its centre inside [u - half_x, u + half_x] iff j in [u - half_x - 1/2, u + half_x - 1/2];
    # floor and ceil widen that by up to a pixel, which the exact alpha test then trims.
    x0, x1 = torch.floor(u - half_x - 0.5), torch.ceil(u + half_x - 0.5)
    y0, y1 = torch.floor(v - half_y - 0.5), torch.ceil(v + half_y - 0.5)
    if settings.footprint_sigmas is not None:
        middle = (s_xx + s_yy) / 2
        lambda_max = middle + torch.sqrt((middle.square() - (s_xx * s_yy - s_xy.square())).clamp(min=0))
        half = settings.footprint_sigmas * torch.sqrt(lambda_max)
        x0, x1 = torch.maximum(x0, torch.ceil(u - half - 0.5)), torch.minimum(x1, torch.floor(u + half - 0.5))
        y0, y1 = torch.maximum(y0, torch.ceil(v - half - 0.5)), torch.minimum(y1, torch.floor(v + half - 0.5))
    box = torch.stack([x0, x1, y0, y1], dim=-1)
    visible = (
        (projection.depths > NEAR_PLANE)
        & torch.isfinite(projection.depths)
        & (k >= 0)
        & torch.isfinite(box).all(dim=-1)
        & (x1 >= 0)
        & (x0 <= width - 1)
        & (y1 >= 0)
        & (y0 <= height - 1)
        & (x0 <= x1)
        & (y0 <= y1)
    )
    limits = torch.tensor([width - 1, width - 1, height - 1, height - 1], dtype=torch.float64)
    box = torch.minimum(torch.nan_to_num(box).clamp(min=0), limits)
    bbox = torch.where(visible.unsqueeze(-1), box, torch.zeros_like(box)).to(torch.int32)

    keys = projection.depths.detach()
    if settings.half_precision_depth:
        keys = keys.clamp(max=torch.finfo(torch.float16).max).to(torch.float16)
    keys = torch.where(visible, keys, torch.full_like(keys, float("inf")))
    order = torch.sort(keys, dim=-1, stable=True).indices.to(torch.int32)
    radius2 = torch.where(visible, radius2, torch.zeros_like(radius2))
    return Footprints(bbox=bbox, visible=visible, order=order, counts=visible.sum(dim=-1), radius2=radius2)
