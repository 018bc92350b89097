"""The detail stage of ``pghm fit``: a detail layer (:mod:`pghm.model.detail`) trained on the fitted avatar.

After stage 2 (and the pose settling) the latent, the network and the pose corrections are frozen
and only the layer's 2L residuals train, with the fit's loss on the training frames in their
corrected poses:

    D* = argmin_D  L(render(avatar + D, pose + delta), image)

A step costs a forward pass of the U-Net (in its faster inference layout) and a render of four
times the Gaussians, and no backward pass through the network: the residuals are leaves right
before the activations. Each residual is seen only by the pixels its Gaussian covers, so the
stage learns what the U-Net's smooth maps and the L texels cannot hold (print, seams, folds).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from pghm.model.pghm import PGHM
from pghm.train.data import PoseCorrections, TrainingData
from pghm.train.loop import AvatarObjective, LoopConfig, LoopState, run_stage
from pghm.train.run_setup import GeometryCache

DETAIL_LR = 1e-2
"""Default Adam learning rate of the residuals (colour logits, and the lift before tanh): a texel's
colour logit moves by about this much per step that sees it."""


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
