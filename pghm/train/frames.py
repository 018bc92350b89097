"""A subject's frames drawn by an avatar as ``pghm eval`` scores them: the render and its target.

The avatar's dynamic Gaussians (I_d) in each frame's pose and camera, on black with their alpha,
and both the render and the frame's stored image on a background colour (on white the stored image
itself, the paper's measure; elsewhere the image moved through its alpha matte,
:mod:`pghm.train.background`). Eval, the fit's choice of a detail layer and the benchmarks share
them, so they all score the same pictures.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch import Tensor

from pghm.body.pose import BodyPose
from pghm.device import move
from pghm.io.avatar import Avatar, avatar_geometry
from pghm.model.evaluator import CachedEvaluator
from pghm.splat import render
from pghm.train.background import BLACK, WHITE, composite_render, composite_target
from pghm.train.data import PoseCorrections, Sample, TrainingData


def render_images(
    avatar: Avatar,
    data: TrainingData,
    indices: list[int],
    body_model_path: str | None = None,
    corrections: PoseCorrections | None = None,
) -> Iterator[tuple[Sample, Tensor, Tensor]]:
    """Yield (sample, render on black (3, H, W), alpha (H, W)) of the dynamic Gaussians, one image
    at a time; each sample's pose through ``corrections`` (on the avatar's device) when given.
    The model renders on the avatar's device; samples and images are on the CPU."""
    device = avatar.device
    evaluator = CachedEvaluator(avatar.model.eval(), avatar_geometry(avatar, body_model_path=body_model_path))
    identity = avatar.identity_map()
    for index in indices:
        sample = data.load(0, index)
        rotations, translation = move(sample.rotations[None], device), move(sample.translation[None], device)
        if corrections is not None:
            with torch.no_grad():
                frame = torch.tensor([sample.frame_key], device=device)
                rotations, translation = corrections(frame, rotations, translation)
        pose = BodyPose(rotations, translation)
        g = evaluator.evaluate(identity, pose, move(sample.camera.centre.float(), device)).dynamic
        with torch.no_grad():
            drawn = render(g.means[0], g.scales[0], g.colors[0], g.opacities[0], sample.camera, background=BLACK)
        yield sample, drawn.rgb.permute(2, 0, 1).cpu(), drawn.alpha.cpu()


def on_background(sample: Sample, rgb_on_black: Tensor, alpha: Tensor, background: tuple[float, float, float]):
    """(target, render), each (3, H, W) in [0, 1], on ``background``: on white the stored image
    (the paper's measure), elsewhere the image moved through its alpha matte."""
    colour = torch.tensor(background, dtype=rgb_on_black.dtype, device=rgb_on_black.device).view(3, 1, 1)
    image = composite_render(rgb_on_black, alpha[None], colour).clamp(0, 1)
    target = sample.image if background == WHITE else composite_target(sample.image, sample.mask, colour)
    return target, image
