"""The detail stage of ``pghm fit``: a detail layer (:mod:`pghm.model.detail`) trained on the fitted avatar.

After stage 2 (and the pose settling) the latent, the network and the pose corrections are frozen
and only the layer's 2L residuals train, with the fit's loss on the training frames in their
corrected poses:

    D* = argmin_D  L(render(avatar + D, pose + delta), image)

A step costs a forward pass of the U-Net (in its faster inference layout) and a render of four
times the Gaussians, and no backward pass through the network: the residuals are leaves right
before the activations. The loss scores the dynamic render alone, counted for both
(:class:`pghm.train.loop.AvatarObjective`'s ``dynamic_only``): the set the avatar is shown with and
the validation scores, at half the splatting. Each residual is seen only by the pixels its Gaussian covers, so the
stage learns what the U-Net's smooth maps and the L texels cannot hold (print, seams, folds).

Whether a video gains from the layer depends on how well its frames agree with each other: it
sharpens a static camera's slow turn and blurs nothing, but on a hand-held video whose outline
moves a pixel from frame to frame it draws sharp edges in the wrong place. So the fit validates it
(:func:`validation_images`): every k-th training frame is held out of this stage, and the layer is
kept only when it draws those frames closer than the avatar without it, by the summed squared error
on white in the frames' corrected poses (:func:`squared_error`). The held frames were seen by the
avatar's earlier stages and not by the layer, which favours the avatar without it: the layer is
kept only when its gain outweighs that.

The layer is validated as it trains, every :data:`CHECK_EVERY` steps (:func:`validated_detail`),
and the stage stops as soon as the answer is known: once the best layer so far beats the avatar
without one, when the held frames' error falls by less than :data:`MIN_GAIN` over a check (the
layer has stopped paying; that best layer is kept); while it does not, when, falling at its last
rate for the steps left, it would not get below the avatar's (the layer cannot pay in time;
dropped). A layer still losing is not stopped for a slow check alone: its error may plateau for
one check and fall again, and stopping there made a keep-or-drop decision on a knife's edge
(docs/lab/fit-speed.md). A video whose layer loses is decided after a fraction of the stage's steps.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import torch
from torch import Tensor, nn

from pghm.io.avatar import Avatar
from pghm.model.pghm import PGHM
from pghm.train.background import WHITE
from pghm.train.data import PoseCorrections, TrainingData
from pghm.train.frames import on_background, render_images
from pghm.train.loop import AvatarObjective, LoopConfig, LoopState, run_stage
from pghm.train.plan import Budget
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
MAX_VALIDATION_IMAGES = 12
"""Most held-out frames that validate a layer: a longer video holds every k-th frame with k raised so
that no more are held. The check compares the same frames with and without the layer, which a dozen
spread over the video decide; each check renders them all (docs/training.md, "Detail layer")."""
CHECK_EVERY = 20
"""Steps of the detail stage between validations of its layer (:func:`validated_detail`): a
validation renders the held frames once (a few steps' time), five of them in the default 100 steps."""
MIN_GAIN = 0.01
"""Least fall of the held frames' error over one check (a share of it) that keeps the stage going
once its layer beats the avatar without one: below it the layer has stopped paying for its steps (on
the synthetic exercise video the error fell 0.25 % from step 40 to 60, 1.1 % to 80, then rose;
docs/lab/fit-speed.md)."""


def validation_images(images: Sequence[int], every: int) -> list[int]:
    """The middle image of each run of ``every`` consecutive training ``images``, the runs made longer
    where that would hold more than :data:`MAX_VALIDATION_IMAGES`: the frames that validate the
    detail layer, spread over the whole video. Empty for ``every`` 0."""
    if not every:
        return []
    every = max(every, math.ceil(len(images) / MAX_VALIDATION_IMAGES))
    return [int(i) for i in images[every // 2 :: every]]


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
    body_model_path: str | None = None,
    validate=None,
    budget: Budget | None = None,
) -> tuple[PGHM, LoopState]:
    """``model`` with a detail layer trained for ``config.steps`` steps on ``data`` (one subject), the
    personal ``latent`` (1, C, L, L), the network and the ``corrections`` frozen, on the latent's device;
    ``model`` is unchanged.

    ``validate``: called with the model, the stage's state and its planned steps every
    :data:`CHECK_EVERY` steps (and before the first); training stops when it returns True.
    ``budget``: the fit's plan, which may shorten the stage to the time left. Returns the new model
    (in eval mode) and the stage's :class:`LoopState`.
    """
    detailed = model.with_detail().to(latent.device).eval()
    for p in detailed.parameters():
        p.requires_grad_(False)
    if corrections is not None:
        corrections.requires_grad_(False)
    maps = detailed.detail.maps.requires_grad_(True)
    objective = AvatarObjective(detailed, latent.detach(), corrections, config.loss, lpips, dynamic_only=True)
    geometries = GeometryCache(data, detailed.config, body_model_path, latent.device)
    optimizer = torch.optim.Adam([maps], lr=lr)
    state, steps = LoopState(), config.steps
    stop = validate is not None and validate(detailed, state, steps)
    while state.step < steps and not stop:
        end = min(state.step + CHECK_EVERY, steps) if validate is not None else steps
        state = run_stage(
            objective=objective,
            trainable=[maps],
            optimizer=optimizer,
            data=data,
            geometry_of=geometries,
            config=replace(config, steps=end),
            checkpoint=None,  # stage 2's end stays the fit's checkpoint: --resume reruns this stage (a minute)
            state=state,
            extra={"stage": 3},
            description="fit: detail",
        )
        if budget is not None:
            budget.progress(state.step)
            steps = min(steps, budget.steps(state.step))
        stop = validate is not None and validate(detailed, state, steps)
    maps.requires_grad_(False)
    return detailed, state


class DetailValidation:
    """The detail layer's validation as it trains (module doc): called every :data:`CHECK_EVERY`
    steps with the model, it scores the held frames (``score``: their squared error drawn by a
    model), keeps the best layer so far, and says when to stop. ``without``: the held frames'
    squared error without a layer; ``images``: how many they are."""

    def __init__(self, score: Callable[[PGHM], float], without: float, images: int) -> None:
        self.score, self.without, self.images = score, without, images
        self.errors: list[tuple[int, float]] = []
        self.best: tuple[float, int, Tensor] | None = None
        self.why = ""

    def __call__(self, model: PGHM, state: LoopState, steps: int) -> bool:
        error = self.score(model)
        self.errors.append((state.step, error))
        if state.step and (self.best is None or error < self.best[0]):  # a trained layer, not the zero one
            self.best = (error, state.step, model.detail.maps.detach().clone())
        if len(self.errors) < 2:
            return False
        (before_step, before), left = self.errors[-2], steps - state.step
        beats = self.best is not None and self.best[0] < self.without
        if beats and error >= before * (1.0 - MIN_GAIN):
            self.why = f"the held frames' error stopped falling by {MIN_GAIN:.0%} a check at step {state.step}"
            return True
        rate = (before - error) / max(state.step - before_step, 1)
        if error > self.without and error - rate * left > self.without:
            self.why = f"at step {state.step} the layer could not beat the avatar without one in the steps left"
            return True
        return False

    def record(self) -> dict:
        """What the avatar's metadata says of the decision."""
        best_error, best_step = (self.best[0], self.best[1]) if self.best else (float("inf"), 0)
        return {
            "kept": best_error < self.without,
            "validation_images": self.images,
            "error_without": self.without,
            "error_with": best_error,
            "best_step": best_step,
            "errors": [[step, round(error, 1)] for step, error in self.errors],
            **({"stopped": self.why} if self.why else {}),
        }


def validated_detail(
    avatar: Avatar,
    data: TrainingData,
    held: list[int],
    corrections: PoseCorrections | None,
    config: LoopConfig,
    lr: float,
    lpips: nn.Module | None,
    body_model_path: str | None = None,
    budget: Budget | None = None,
) -> tuple[PGHM | None, LoopState, dict]:
    """A detail layer for ``avatar`` trained on ``data`` without the ``held`` images and kept if it
    draws those closer (module doc); ``held`` empty: trained for all its steps and kept. Returns
    the model with its best layer (None when dropped), the stage's state and the decision's record."""
    if not held:
        model, state = train_detail(
            avatar.model, avatar.latent, corrections, data, config, lr, lpips, body_model_path, None, budget
        )
        return model, state, {"kept": True}
    without = squared_error(avatar, data, held, corrections)
    score = lambda model: squared_error(replace(avatar, model=model), data, held, corrections)
    validation = DetailValidation(score, without, len(held))
    trained_on = data.restricted(sorted(set(int(i) for i in data.images[0]) - set(held)))
    model, state = train_detail(
        avatar.model, avatar.latent, corrections, trained_on, config, lr, lpips, body_model_path, validation, budget
    )
    record = validation.record()
    if not record["kept"]:
        return None, state, record
    with torch.no_grad():
        model.detail.maps.copy_(validation.best[2])
    return model, state, record
