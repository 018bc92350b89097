"""Images at a lower resolution for the coarse steps of a stage or a settling pass.

A coarse step renders and scores a sample at 1 / :data:`COARSE_FACTOR` of its resolution: a
quarter of the pixels, so a quarter of the losses and less of the splatting (which walks each
Gaussian's footprint in blocks of 8 pixels), while the network (which works on UV maps, not pixels)
costs what it costs at full resolution: a coarse stage step is about 0.75 of a full one. What a pose's error or an
avatar's broad colours need, an outline displaced by pixels and regions many pixels wide, half
the resolution still shows; the fine steps that follow add what it does not.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch.nn.functional as F
from torch import Tensor

from pghm.splat import Camera
from pghm.train.data import Sample
from pghm.train.person_crop import Crop

COARSE_FACTOR = 2
"""A coarse step's image is this many times smaller on each side: a pose's error is an outline
displaced by pixels, which half the resolution still shows, at a quarter of the pixels."""
COARSE_MIN_SIDE = 64
"""Smallest side of a coarse image, in pixels: below it the coarse steps keep the full resolution.
A small image halved leaves the person a few SSIM windows across, whose gradients mislead the
pose (the 64-pixel test subject's settled track ends further off)."""


def coarse_sample(sample: Sample, factor: int = COARSE_FACTOR) -> Sample:
    """``sample`` at 1/``factor`` of its resolution: image and mask averaged over factor x factor
    blocks (a last row or column that fills no block dropped), the camera's focal lengths and
    principal point divided by ``factor`` (pixel i's centre is at i + 1/2, so coarse pixel i covers
    fine pixels factor i .. factor i + factor - 1 exactly), and the crop's box likewise."""
    camera = sample.camera
    height, width = camera.height // factor, camera.width // factor

    def pooled(image: Tensor) -> Tensor:
        return F.avg_pool2d(image[None, :, : height * factor, : width * factor], factor)[0]

    fx, fy, cx, cy = (value / factor for value in (camera.fx, camera.fy, camera.cx, camera.cy))
    coarse = Camera(fx, fy, cx, cy, width, height, camera.world_to_camera)
    crop = sample.crop
    if crop is not None:
        frame = (crop.frame_width // factor, crop.frame_height // factor)
        crop = Crop(crop.x0 // factor, crop.y0 // factor, width, height, *frame)
    return replace(sample, image=pooled(sample.image), mask=pooled(sample.mask), camera=coarse, crop=crop)


def coarse_samples(samples: list[Sample]) -> list[Sample]:
    """The samples (of one size) of a coarse step: each :func:`coarse_sample`, or all as they are when
    halving them would leave a side under :data:`COARSE_MIN_SIDE`."""
    camera = samples[0].camera
    if min(camera.width, camera.height) // COARSE_FACTOR < COARSE_MIN_SIDE:
        return samples
    return [coarse_sample(sample) for sample in samples]


def coarse_steps(share: float, steps: int) -> int:
    """How many of a stage's ``steps`` are coarse when its first ``share`` are: ceil(share * steps),
    the step numbers below share * steps (the loop and the plan's cost model count the same ones)."""
    return math.ceil(share * steps)
