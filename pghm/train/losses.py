"""The paper's training objective and the evaluation metrics, one implementation of each.

    L = l1 [L1(I_s, I) + L1(I_d, I)] + l2 [(1 - SSIM)(I_s, I) + (1 - SSIM)(I_d, I)]
      + l3 [LPIPS(I_s, I) + LPIPS(I_d, I)] + l4 L_reg

with (l1, l2, l3, l4) = (0.8, 0.2, 0.2, 0.1), plus two terms the paper does not have: a
Gaussian prior on the pose corrections and the silhouette term

    l_sil [S(A_s, m) + S(A_d, m)],   S(A, m) = mean over pixels |A - m|,

the L1 distance of the renders' accumulated alpha A to the target's mask m. SSIM uses a Gaussian window of 11 taps,
sigma 1.5, K1 = 0.01, K2 = 0.03 over the valid region (pytorch-msssim, which implements
exactly Wang et al. 2004's definition); the same function is the evaluation metric.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from pytorch_msssim import ssim as _ssim
from torch import Tensor

from pghm.errors import PghmError

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5


@dataclass(frozen=True)
class LossWeights:
    """Weights of the objective's terms (the paper's lambda_1..lambda_4)."""

    l1: float = 0.8
    ssim: float = 0.2
    lpips: float = 0.2
    regularizer: float = 0.1
    pose_prior: float = 0.0
    """Weight of the Gaussian prior on the pose corrections (not in the paper; 0: off), see
    :meth:`pghm.train.data.PoseCorrections.prior`."""
    silhouette: float = 0.0
    """Weight of the silhouette term (not in the paper; 0: off), see :func:`silhouette`."""

    def __post_init__(self) -> None:
        negative = [name for name, value in asdict(self).items() if not value >= 0]
        if negative:
            raise PghmError(f"loss weights must be >= 0: {', '.join(negative)}")


def ssim(x: Tensor, y: Tensor) -> Tensor:
    """(B,) SSIM of images (B, 3, H, W) in [0, 1]; 1 for identical images."""
    return _ssim(x, y, data_range=1.0, size_average=False, win_size=SSIM_WINDOW, win_sigma=SSIM_SIGMA)


def psnr(x: Tensor, y: Tensor, pixel_share: Tensor | None = None) -> Tensor:
    """(B,) PSNR in dB of images in [0, 1]; +inf for identical images. ``pixel_share`` (B,): crops'
    shares of their frames' pixels, for the PSNR of the frames (the same outside the crops)."""
    mse = (x - y).square().flatten(1).mean(1)
    if pixel_share is not None:
        mse = mse * pixel_share
    return torch.where(mse > 0, -10.0 * torch.log10(mse), torch.full_like(mse, math.inf))


def silhouette(alpha: Tensor, mask: Tensor, pixel_share: Tensor | None = None) -> Tensor:
    """(B,) mean over pixels of |A - m|: accumulated alphas (B, 1, H, W) against masks (B, 1, H, W)
    (of the full frames for crops with ``pixel_share`` (B,), as :func:`psnr`).

    On white a semi-transparent fringe outside the mask costs nothing in the photometric terms;
    here it costs its opacity, and a hole inside the mask its transparency.
    """
    mean = (alpha - mask).abs().flatten(1).mean(1)
    return mean if pixel_share is None else mean * pixel_share


def image_losses(render: Tensor, target: Tensor, lpips=None, area: Tensor | None = None) -> dict[str, Tensor]:
    """Per-image terms (each (B,)) between renders and targets (B, 3, H, W).

    ``area``: (B, 2) each image's share of its full frame's pixels and SSIM windows when it is a
    crop (:mod:`pghm.train.person_crop`): the terms are then the full frame's."""
    terms = {
        "l1": (render - target).abs().flatten(1).mean(1),
        "dssim": 1.0 - ssim(render, target),
    }
    if lpips is not None:
        terms["lpips"] = lpips(render, target)
    if area is not None:
        terms = {key: value * area[:, 1 if key == "dssim" else 0] for key, value in terms.items()}
    return terms


def objective(
    static_render: Tensor,
    dynamic_render: Tensor,
    target: Tensor,
    regularizer: Tensor,
    weights: LossWeights = LossWeights(),
    lpips=None,
    area: Tensor | None = None,
) -> tuple[Tensor, dict[str, float]]:
    """The paper's loss on both renders (B, 3, H, W), averaged over the batch (crops: ``area``
    as in :func:`image_losses`).

    Returns the scalar loss and a dict of its terms for logging.
    """
    total = weights.regularizer * regularizer
    log = {"reg": float(regularizer.detach())}
    for name, render in (("s", static_render), ("d", dynamic_render)):
        terms = image_losses(render, target, lpips, area)
        total = total + weights.l1 * terms["l1"].mean() + weights.ssim * terms["dssim"].mean()
        if "lpips" in terms:
            total = total + weights.lpips * terms["lpips"].mean()
        log.update({f"{key}_{name}": float(value.detach().mean()) for key, value in terms.items()})
    log["loss"] = float(total.detach())
    return total, log
