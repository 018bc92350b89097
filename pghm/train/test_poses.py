"""Test-time pose refinement: each held-out frame's pose fitted to its own image, the avatar frozen.

A monocular capture's poses carry its estimator's error. ``pghm fit`` corrects the poses of the
frames it trains on (per-frame corrections in stage 2), but a held-out frame keeps its estimate,
and an estimate a few pixels off leaves an error along every edge of the render: PSNR then
measures the pose estimator, not the avatar. Evaluations of monocular avatars therefore refine
the held-out poses against their images with the model frozen (InstantAvatar and GART on
PeopleSnapshot). This module does it with the fit's own objective and corrections:

    delta* = argmin_delta  L(render(avatar, pose + delta), image) + w_p P(delta)

L is the fit's loss (L1 + SSIM + silhouette, on a random background colour per image and
step), P the fit's Gaussian prior on the corrections (:meth:`PoseCorrections.prior`, as wide
as the subject's stated pose noise) with its weight w_p; only delta changes (the estimator's
joints and the root translation, one row per frame). A frame's row depends on its image
alone, so one step over all frames is one step of each frame's own problem. Appearance is
untouched: the latent and every network weight stay as fitted.
"""

from __future__ import annotations

import logging

import torch
from tqdm import tqdm

from pghm.body import load_body
from pghm.io.avatar import Avatar, avatar_geometry
from pghm.train.background import TRAINING_BACKGROUND, draw_backgrounds
from pghm.train.data import PoseCorrections, TrainingData
from pghm.train.fit import POSE_LR, FitConfig
from pghm.train.loop import AvatarObjective

log = logging.getLogger(__name__)

IMAGES_PER_BATCH = 2
"""Images rendered together in one forward pass (the fit's batch): memory, not the result."""
REFINE_SEED_SALT = 0x7E57
"""Keeps the refinement's background draws apart from the fit's (same seed, same step)."""


def refine_test_poses(
    avatar: Avatar,
    data: TrainingData,
    steps: int,
    body_model_path: str | None = None,
    seed: int = 0,
    progress: bool = True,
    images: list[int] | None = None,
) -> PoseCorrections:
    """Pose corrections of the frames of ``data`` (one subject, typically its test split) fitted
    to their images for ``steps`` Adam steps, ``avatar`` frozen.

    ``images``: only these image indices of ``data`` (None: all of them). Returns corrections
    indexed by :attr:`Sample.frame_key`; the other frames keep zero rows.
    """
    body = load_body(avatar.body_name, body_model_path)
    geometry = avatar_geometry(avatar, body_model_path=body_model_path)
    corrections = data.pose_corrections(body)
    weights = FitConfig().stage2.loss  # the fit's own loss, so a frozen avatar sees the same objective
    model = avatar.model.eval()
    frozen = [p for p in model.parameters() if p.requires_grad]
    for p in frozen:
        p.requires_grad_(False)
    objective = AvatarObjective(model, avatar.identity_map(), corrections, weights, lpips=None)
    optimizer = torch.optim.Adam(corrections.parameters(), lr=POSE_LR)
    images = [int(i) for i in (data.images[0] if images is None else images)]
    # Read once: every step renders the same images.
    batches = [data.load_group(0, images[k : k + IMAGES_PER_BATCH]) for k in range(0, len(images), IMAGES_PER_BATCH)]
    try:
        for step in tqdm(range(steps), desc="refine test poses", disable=not progress, dynamic_ncols=True):
            optimizer.zero_grad(set_to_none=False)
            for position, samples in enumerate(batches):
                if not samples:
                    continue
                height, width = samples[0].camera.height, samples[0].camera.width
                backgrounds = draw_backgrounds(
                    TRAINING_BACKGROUND, len(samples), height, width, (seed, REFINE_SEED_SALT, step, position)
                )
                loss, _ = objective(samples, geometry, backgrounds)
                loss.backward()
            grads = [p.grad for p in corrections.parameters()]
            if not all(bool(torch.isfinite(g).all()) for g in grads):
                log.warning("test-pose refinement step %d: non-finite gradient; step skipped", step)
                continue
            optimizer.step()
    finally:
        for p in frozen:
            p.requires_grad_(True)
    return corrections.requires_grad_(False)
