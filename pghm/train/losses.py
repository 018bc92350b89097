"""The paper's training objective and the evaluation metrics, one implementation of each.

    L = l1 [L1(I_s, I) + L1(I_d, I)] + l2 [(1 - SSIM)(I_s, I) + (1 - SSIM)(I_d, I)]
      + l3 [LPIPS(I_s, I) + LPIPS(I_d, I)] + l4 L_reg

with (l1, l2, l3, l4) = (0.8, 0.2, 0.2, 0.1), plus two terms the paper does not have: a
Gaussian prior on the pose corrections and the silhouette term

    l_sil [S(A_s, m) + S(A_d, m)],   S(A, m) = mean over pixels |A - m|,

the L1 distance of the renders' accumulated alpha A to the target's mask m. SSIM uses a Gaussian window of 11 taps,
sigma 1.5, K1 = 0.01, K2 = 0.03 over the valid region (pytorch-msssim, which implements
exactly Wang et al. 2004's definition) as the evaluation metric; the loss computes the same
formula with the targets' statistics shared by both renders (:class:`TargetSsim`, tested equal).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from pytorch_msssim import ssim as _ssim
from torch import Tensor

from pghm.device import constant
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


SSIM_K1, SSIM_K2 = 0.01, 0.03


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Tensor:
    """(size,) float32 normalised Gaussian taps exp(-k^2 / (2 sigma^2)), k = -size//2 .. size//2."""
    taps = torch.arange(size, dtype=torch.float32) - size // 2
    window = torch.exp(-(taps**2) / (2 * sigma**2))
    return window / window.sum()


def window_means(images: Tensor, window: Tensor) -> Tensor:
    """(B, C, H - k + 1, W - k + 1): each channel of (B, C, H, W) filtered by the separable window
    (k,), valid positions only, rows first (as pytorch-msssim)."""
    channels, size = images.shape[1], window.numel()
    taps = window.to(images)
    rows = F.conv2d(images, taps.view(1, 1, size, 1).expand(channels, 1, size, 1), groups=channels)
    return F.conv2d(rows, taps.view(1, 1, 1, size).expand(channels, 1, 1, size), groups=channels)


class TargetSsim:
    """SSIM of renders against one batch of targets (B, 3, H, W), the targets' window statistics
    computed once: the objective compares two renders (static, dynamic) with the same targets.

    The same formula as :func:`ssim` (Wang et al. 2004, data range 1), which it equals to float
    rounding (tested); one grouped convolution of [x, x^2, x y] per render instead of five.
    """

    def __init__(self, target: Tensor) -> None:
        self.window = constant(tuple(gaussian_window().tolist()), target.dtype, target.device)
        self.target = target
        mu, second = window_means(torch.cat([target, target * target], 1), self.window).chunk(2, 1)
        self.mu, self.mu_sq = mu, mu.square()
        self.variance = second - self.mu_sq

    def __call__(self, render: Tensor) -> Tensor:
        """(B,) SSIM of renders (B, 3, H, W) against the targets."""
        stats = torch.cat([render, render * render, render * self.target], 1)
        mu, second, cross = window_means(stats, self.window).chunk(3, 1)
        mu_sq, mu_mu = mu.square(), mu * self.mu
        c1, c2 = SSIM_K1**2, SSIM_K2**2
        cs = (2 * (cross - mu_mu) + c2) / ((second - mu_sq) + self.variance + c2)
        ssim_map = ((2 * mu_mu + c1) / (mu_sq + self.mu_sq + c1)) * cs
        return ssim_map.flatten(2).mean(-1).mean(1)


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


def image_losses(
    render: Tensor, target: Tensor, lpips=None, area: Tensor | None = None, target_ssim: TargetSsim | None = None
) -> dict[str, Tensor]:
    """Per-image terms (each (B,)) between renders and targets (B, 3, H, W).

    ``area``: (B, 2) each image's share of its full frame's pixels and SSIM windows when it is a
    crop (:mod:`pghm.train.person_crop`): the terms are then the full frame's. ``target_ssim``:
    the targets' SSIM statistics when already computed."""
    terms = {
        "l1": (render - target).abs().flatten(1).mean(1),
        "dssim": 1.0 - (target_ssim or TargetSsim(target))(render),
    }
    if lpips is not None:
        terms["lpips"] = lpips(render, target)
    if area is not None:
        terms = {key: value * area[:, 1 if key == "dssim" else 0] for key, value in terms.items()}
    return terms


def objective(
    static_render: Tensor | None,
    dynamic_render: Tensor,
    target: Tensor,
    regularizer: Tensor,
    weights: LossWeights = LossWeights(),
    lpips=None,
    area: Tensor | None = None,
) -> tuple[Tensor, dict[str, Tensor]]:
    """The paper's loss on both renders (B, 3, H, W), averaged over the batch (crops: ``area``
    as in :func:`image_losses`). ``static_render`` None: the dynamic render's terms count twice,
    standing in for the static one's (the same loss when the two renders are equal).

    Returns the scalar loss and a dict of its terms for logging, detached 0-dim tensors where the
    loss is (read to the host once a step, by the caller).
    """
    total = weights.regularizer * regularizer
    log = {"reg": regularizer.detach()}
    target_ssim = TargetSsim(target)
    renders = (("d", dynamic_render),) if static_render is None else (("s", static_render), ("d", dynamic_render))
    count = 3 - len(renders)  # each render's terms count this many times: 2 - 1 = 1 for both renders
    for name, render in renders:
        terms = image_losses(render, target, lpips, area, target_ssim)
        total = total + count * weights.l1 * terms["l1"].mean() + count * weights.ssim * terms["dssim"].mean()
        if "lpips" in terms:
            total = total + count * weights.lpips * terms["lpips"].mean()
        log.update({f"{key}_{name}": value.detach().mean() for key, value in terms.items()})
    log["loss"] = total.detach()
    return total, log
