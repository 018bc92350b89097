"""The detail stage of ``pghm fit``: a detail layer (:mod:`pghm.model.detail`) trained on the fitted avatar.

After stage 2 (and the pose settling) the latent, the network and the pose corrections are frozen
and only the layer's 2L residuals train, with the fit's loss on the training frames in their
corrected poses:

    D* = argmin_D  L(render(avatar + D, pose + delta), image)

A step costs a forward pass of the U-Net (in its faster inference layout) and a render of four
times the Gaussians, and no backward pass through the network: the residuals are leaves right
before the activations. Each residual is seen only by the pixels its Gaussian covers, so the
stage learns what the U-Net's smooth maps and the L texels cannot hold (print, seams, folds).

Whether a video gains from the layer depends on how well its frames agree with each other: it
sharpens a static camera's slow turn and blurs nothing, but on a hand-held video whose outline
moves a pixel from frame to frame it draws sharp edges in the wrong place. So the fit validates it
(:func:`validation_images`): every k-th training frame is held out of this stage, and the layer is
kept only when it draws those frames closer than the avatar without it, by the summed squared error
on white in the frames' corrected poses (:func:`squared_error`). The held frames were seen by the
avatar's earlier stages and not by the layer, which favours the avatar without it: the layer is
kept only when its gain outweighs that.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from torch import Tensor, nn

from pghm.io.avatar import Avatar
from pghm.model.pghm import PGHM
from pghm.train.background import WHITE
from pghm.train.data import PoseCorrections, TrainingData
from pghm.train.frames import on_background, render_images
from pghm.train.loop import AvatarObjective, LoopConfig, LoopState, run_stage
from pghm.train.run_setup import GeometryCache

DETAIL_LR = 1e-2
"""Default Adam learning rate of the residuals (colour logits, and the lift before tanh): a texel's
colour logit moves by about this much per step that sees it."""
DETAIL_STEPS = 100
"""Default steps of the detail stage: 150 gain 0.06 dB more for half as much time again, 300 no more
(docs/lab/detail-layer.md)."""
VALIDATION_EVERY = 4
"""Every this-many training frames, one is held out of the detail stage to validate it."""
MIN_VALIDATION_IMAGES = 4
"""Fewest held-out frames that validate a layer; a video with fewer gets none (nothing to decide on)."""


def validation_images(images: Sequence[int], every: int) -> list[int]:
    """The middle image of each run of ``every`` consecutive training ``images``: the frames that
    validate the detail layer, spread over the whole video. Empty for ``every`` 0."""
    return [int(i) for i in images[every // 2 :: every]] if every else []


def squared_error(avatar: Avatar, data: TrainingData, images: list[int], corrections: PoseCorrections | None) -> float:
    """The summed squared error of ``avatar``'s renders on white against ``images`` of ``data``, each
    in its pose through ``corrections``: on the crops when ``data`` crops (outside them both are white)."""
    total = 0.0
    for sample, rgb_on_black, alpha in render_images(avatar, data, images, corrections=corrections):
        target, image = on_background(sample, rgb_on_black, alpha, WHITE)
        total += float((image.double() - target.double()).square().sum())
    return total


def train_detail(
    model: PGHM,
    latent: Tensor,
    corrections: PoseCorrections | None,
    data: TrainingData,
    config: LoopConfig,
    lr: float,
    lpips: nn.Module | None,
    checkpoint: Path,
    body_model_path: str | None = None,
) -> tuple[PGHM, LoopState]:
    """``model`` with a detail layer trained for ``config.steps`` steps on ``data`` (one subject), the
    personal ``latent`` (1, C, L, L), the network and the ``corrections`` frozen, on the latent's device;
    ``model`` is unchanged.

    Returns the new model (in eval mode) and the stage's :class:`LoopState`.
    """
    detailed = model.with_detail().to(latent.device).eval()
    for p in detailed.parameters():
        p.requires_grad_(False)
    if corrections is not None:
        corrections.requires_grad_(False)
    maps = detailed.detail.maps.requires_grad_(True)
    objective = AvatarObjective(detailed, latent.detach(), corrections, config.loss, lpips)
    geometries = GeometryCache(data, detailed.config, body_model_path, latent.device)
    optimizer = torch.optim.Adam([maps], lr=lr)
    state = run_stage(
        objective=objective,
        trainable=[maps],
        optimizer=optimizer,
        data=data,
        geometry_of=geometries,
        config=config,
        checkpoint=checkpoint,
        state=LoopState(),
        extra={"stage": 3},
        description="fit: detail",
    )
    maps.requires_grad_(False)
    return detailed, state
