"""pghm's splat spec on CUDA through gsplat: the one place pghm's inputs become gsplat's arguments.

``gsplat.rasterization`` (gsplat 1.5.3, its 3DGS path) with ``eps2d = COV_DILATION``,
``near_plane = NEAR_PLANE``, ``rasterize_mode="classic"``, identity quaternions and the
isotropic scale on all three axes computes spec steps 1-6 of :mod:`pghm.splat` in float32,
with these differences of its kernels (docs/splat.md, "GPU (gsplat)", gives their size):

- alpha is clamped to GSPLAT_ALPHA_MAX (0.999), not ALPHA_MAX (0.99): it differs where
  o exp(-d^T Q d / 2) > 0.99, a disc of 0.14 sigma around the centre of an opaque Gaussian;
- a pixel stops before the Gaussian that would take its transmittance to GSPLAT_STOP (1e-4)
  or below, and composites nothing behind it (the spec never stops);
- its footprint is capped at GSPLAT_FOOTPRINT_SIGMAS (3.33) sigma, which cuts nothing for
  opacities up to 1: the exact footprint reaches 3.33 sigma only at opacity 1.003;
- its frustum clamp in J is (W - cx) / fx + 0.15 W / fx on the right and cx / fx + 0.15 W / fx
  on the left, the spec's 1.3 W / (2 fx) on both sides only for a centred principal point;
- it orders each tile by float32 depth, the spec by float64 (Gaussians closer in depth than
  float32 resolves may composite in another order).

gsplat is an optional extra (``pip install 'pghm[gpu]'``); it compiles its CUDA kernels on
first use. Its pure-PyTorch projection runs on the CPU, so the tests hold this mapping to the
CPU splatter without a GPU (tests/test_splat_gsplat.py).
"""

from __future__ import annotations

import importlib
from typing import Any

import torch
from torch import Tensor

from pghm.device import constant
from pghm.errors import PghmError
from pghm.splat.camera import Camera
from pghm.splat.spec import COV_DILATION, NEAR_PLANE

INSTALL_HINT = "pip install 'pghm[gpu]'"
"""How to install gsplat (the ``gpu`` extra pins the version this mapping is written for)."""
GSPLAT_ALPHA_MAX = 0.999
"""gsplat's clamp on alpha (its 3DGS kernels); the spec's is ALPHA_MAX = 0.99."""
GSPLAT_STOP = 1e-4
"""gsplat stops a pixel before the Gaussian that would leave a transmittance at or below this."""
GSPLAT_FOOTPRINT_SIGMAS = 3.33
"""gsplat's cap on a footprint's half-side, in standard deviations of cov2d along each axis."""
DEPTH_MODE = "RGB+D"
IDENTITY_QUATERNION = (1.0, 0.0, 0.0, 0.0)
"""gsplat's (w, x, y, z) rotation of every Gaussian: pghm's are isotropic."""
"""gsplat's render mode whose fourth channel is sum_i t_z,i alpha_i T_i: the spec's depth."""


def load_gsplat() -> Any:
    """The gsplat module; PghmError saying how to install it when it is missing."""
    try:
        return importlib.import_module("gsplat")
    except ImportError:
        raise PghmError(f"rendering on CUDA needs gsplat, which is not installed: {INSTALL_HINT}") from None


def rasterization_arguments(
    means: Tensor,
    scales: Tensor,
    colors: Tensor,
    opacities: Tensor,
    camera: Camera,
    background: Tensor,
    dtype: torch.dtype = torch.float32,
) -> dict[str, Any]:
    """The keyword arguments of ``gsplat.rasterization`` for pghm's inputs (on the means' device).

    Args:
        means: (B, N, 3) world positions mu.
        scales: (B, N) isotropic world standard deviations s.
        colors: (B, N, 3) colours c.
        opacities: (B, N) opacities o.
        camera: one camera or B cameras; image b is seen by camera b.
        background: (3,) colour behind everything.
        dtype: of the tensors; gsplat's kernels take float32, and the tests hold the mapping
            to the spec in float64 through gsplat's torch reference.

    gsplat's batch dimension carries pghm's B with one camera each (its C = 1): means
    (B, N, 3), viewmats (B, 1, 4, 4), Ks (B, 1, 3, 3). The isotropic covariance s^2 I is
    gsplat's identity rotation with the scale s on all three axes; the depth channel's
    background is 0 (gsplat appends it).
    """
    batch, count = opacities.shape
    device = means.device
    quats = constant(IDENTITY_QUATERNION, dtype, device).expand(batch, count, 4)
    pose = camera.world_to_camera.to(device=device, dtype=dtype).expand(batch, 4, 4)
    intrinsics = camera.K.to(device=device, dtype=dtype).expand(batch, 3, 3)
    return {
        "means": means.to(dtype),
        "quats": quats,
        "scales": scales.to(dtype)[..., None].expand(batch, count, 3),
        "opacities": opacities.to(dtype),
        "colors": colors.to(dtype),
        "viewmats": pose[:, None],
        "Ks": intrinsics[:, None],
        "width": camera.width,
        "height": camera.height,
        "near_plane": NEAR_PLANE,
        "eps2d": COV_DILATION,
        "backgrounds": constant(tuple(background.tolist()), dtype, device).expand(batch, 1, 3),
        "render_mode": DEPTH_MODE,
        "rasterize_mode": "classic",
        "packed": False,
        "sh_degree": None,
    }


def render_gsplat(
    means: Tensor, scales: Tensor, colors: Tensor, opacities: Tensor, camera: Camera, background: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """rgb (B, H, W, 3), alpha (B, H, W), depth (B, H, W) in the colors' dtype, through gsplat.

    Inputs as :func:`rasterization_arguments`; gradients reach every Gaussian input and the
    camera's world_to_camera, through gsplat's own backward.
    """
    gsplat = load_gsplat()
    images, alphas, _ = gsplat.rasterization(
        **rasterization_arguments(means, scales, colors, opacities, camera, background)
    )
    images, alphas = images[:, 0].to(colors.dtype), alphas[:, 0, ..., 0].to(colors.dtype)
    return images[..., :3], alphas, images[..., 3]
