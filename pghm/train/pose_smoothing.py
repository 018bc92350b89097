"""Temporal smoothing of a video's estimated poses before training on them.

A per-frame pose estimator's error is largely jitter: independent from frame to frame,
while the true motion is smooth. Averaging each frame's pose with its neighbours'
removes most of the jitter before any photometric refinement sees it; the pose
corrections learned during fitting then start from a much better estimate. ``pghm fit``
leaves it off by default: those corrections decide the result (docs/lab/defaults.md, "Fit:
steps and backgrounds").

Filter: a Gaussian window w_k ~ exp(-k^2 / (2 sigma^2)), |k| <= ceil(3 sigma), over each
run of consecutive frame numbers, truncated and renormalised at the ends of a run:

    t'_f = sum_k w_k t_{f+k}
    R'_f = argmin_{R in SO(3)} sum_k w_k ||R - R_{f+k}||_F^2 = proj_SO(3)(sum_k w_k R_{f+k})

the weighted chordal mean of the rotations, projected by SVD (Procrustes). A rotation
track of constant angular velocity about a fixed axis and a translation of constant
velocity are left unchanged away from the ends of a run.
"""

from __future__ import annotations

import math

import numpy as np
import roma
import torch
from torch import Tensor

from pghm.errors import PghmError

WINDOW_SIGMAS = 3.0
"""Half-width of the window in standard deviations (the weights beyond are below 1.2% of the centre one)."""


def gaussian_window(sigma: float) -> Tensor:
    """(2h + 1,) float64 weights exp(-k^2 / (2 sigma^2)) for k = -h..h, h = ceil(3 sigma); unnormalised."""
    half = math.ceil(WINDOW_SIGMAS * sigma)
    k = torch.arange(-half, half + 1, dtype=torch.float64)
    return torch.exp(-0.5 * (k / sigma) ** 2)


def consecutive_runs(frames: np.ndarray) -> list[np.ndarray]:
    """Positions into ``frames`` (sorted ascending, distinct) split at every gap in the numbering."""
    cuts = np.flatnonzero(np.diff(frames) != 1) + 1
    return np.split(np.arange(len(frames)), cuts)


def smooth_run(rotations: Tensor, translation: Tensor, sigma: float) -> tuple[Tensor, Tensor]:
    """Smooth one run of consecutive frames.

    Args:
        rotations: (F, J, 3) axis-angle.
        translation: (F, 3).
        sigma: standard deviation of the window in frames; 0 returns the input unchanged.

    Returns:
        (F, J, 3) rotations and (F, 3) translation, same dtype as the input.
    """
    if sigma == 0 or len(rotations) < 2:
        return rotations, translation
    window = gaussian_window(sigma)
    half = len(window) // 2
    frames = len(rotations)
    matrices = roma.rotvec_to_rotmat(rotations.double())
    positions = translation.double()
    rotation_sum, translation_sum = torch.zeros_like(matrices), torch.zeros_like(positions)
    weight_sum = torch.zeros(frames, dtype=torch.float64)
    for k, w in zip(range(-half, half + 1), window):
        # Frames f in [lo, hi) have a neighbour f + k inside the run.
        lo, hi = max(0, -k), min(frames, frames - k)
        if lo >= hi:  # the window is longer than the run
            continue
        rotation_sum[lo:hi] += w * matrices[lo + k : hi + k]
        translation_sum[lo:hi] += w * positions[lo + k : hi + k]
        weight_sum[lo:hi] += w
    # The scale of the sum does not change its projection onto SO(3); only the translation is divided.
    smoothed = roma.rotmat_to_rotvec(roma.special_procrustes(rotation_sum))
    return smoothed.to(rotations.dtype), (translation_sum / weight_sum[:, None]).to(translation.dtype)


def smooth_track(frames: np.ndarray, rotations: Tensor, translation: Tensor, sigma: float) -> tuple[Tensor, Tensor]:
    """Smooth a pose track over time, each run of consecutive frames on its own.

    Args:
        frames: (F,) distinct frame numbers, ascending.
        rotations: (F, J, 3) axis-angle, one pose per frame.
        translation: (F, 3).
        sigma: window standard deviation in frames (>= 0; PghmError otherwise).
    """
    if sigma < 0 or not math.isfinite(sigma):
        raise PghmError(f"pose smoothing sigma must be a finite number of frames >= 0, got {sigma}")
    out_rotations, out_translation = rotations.clone(), translation.clone()
    for run in consecutive_runs(frames):
        index = torch.from_numpy(run)
        out_rotations[index], out_translation[index] = smooth_run(rotations[index], translation[index], sigma)
    return out_rotations, out_translation
