"""``pghm fit``: personalise a prior to one subject from a monocular video (paper section
"Personalization with Parametric Avatar Prior").

Stage 1, identity-map adaptation: the decoded identity map is replaced by a new learnable
full-resolution latent (C x L x L, bypassing the Feature Decoder), initialised with the decoded mean of
the bank's latents, and optimised alone; the network is frozen. For poses stated noisier than the
synthetic data's (a capture), each training frame's pose is then settled coarsely against that
stage-1 avatar (:func:`early_track_steps`), so stage 2 learns appearance from aligned frames.
Stage 2, joint tuning: the latent and the U-Net (E_u, E_p, E_v and the decoders) are optimised
together, with per-frame pose corrections when ``refine_poses``; the avatar keeps them as its pose
track (:mod:`pghm.train.pose_track`).
Then, for a capture whose frames stage 2 visits too rarely, the track is settled: every training
frame's correction refined against its image with the avatar frozen, coarse to fine
(:mod:`pghm.train.pose_refine`; :func:`track_steps`), and the frames held out of training are
aligned to their own images the same way (:func:`align_held_out`), so every frame of the video
replays aligned.
Both stages train on crops around the person (:mod:`pghm.train.person_crop`).
Last, a detail layer trains on the frozen avatar and is kept if it draws the training frames held
out of it closer than the avatar without it (:mod:`pghm.train.detail`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from pghm._fault_injection import interrupt_point
from pghm.body import load_body
from pghm.device import move, resolve_precision
from pghm.errors import PghmError
from pghm.io.atomic import Outputs
from pghm.io.avatar import Avatar, PoseTrack, load_avatar, recorded_path, save_avatar
from pghm.model import PGHM, ModelConfig
from pghm.model.detail import DETAIL_FACTOR
from pghm.model.pghm import COMPONENTS
from pghm.subject import ALL_SPLIT
from pghm.train import profile
from pghm.train.background import TRAINING_BACKGROUND
from pghm.train.data import ESTIMATOR_ROTATION_SIGMA, PoseCorrections, TrainingData
from pghm.train.detail import (
    DETAIL_LR,
    DETAIL_STEPS,
    MIN_VALIDATION_IMAGES,
    VALIDATION_EVERY,
    validated_detail,
    validation_images,
)
from pghm.train.loop import (
    AvatarObjective,
    LoopConfig,
    LoopState,
    check_learning_rate,
    check_step_memory,
    check_trained,
    load_checkpoint,
    restore,
    restore_objective,
    run_stage,
    save_checkpoint,
)
from pghm.train.losses import LossWeights
from pghm.train.optim import LazyAdam
from pghm.train.person_crop import CROP_MARGIN
from pghm.train.plan import DETAIL, EARLY_SETTLING, HELD_OUT, POSE_SETTLING, STAGE1, STAGE2, Budget, Phase, describe
from pghm.train.pose_refine import refine_poses
from pghm.train.pose_track import frame_numbers, learned_track, track_corrections
from pghm.train.run_setup import GeometryCache, check_output_room, checkpoint_path, config_record, lpips_for
from pghm.uv.atlas import MAX_RESOLUTION

log = logging.getLogger(__name__)

NETWORK_PARTS = tuple(part for part in COMPONENTS if part != "feature_decoder")
"""What stage 2 tunes: the U-Net and its pose/view encoders (the bank and Feature Decoder are bypassed)."""

FIT_POSE_PRIOR = 5e-4
"""Default weight of the Gaussian prior on the pose corrections when fitting a monocular video.
Without it the corrections drift along the camera's axis and at the extremities, where the image
constrains them little (docs/lab/defaults.md, "Fit: the pose corrections' prior")."""

POSE_LR = 1e-2
"""Learning rate of the pose corrections for poses as noisy as the synthetic data's (2 degrees);
:func:`pose_learning_rate` scales it to a subject's stated noise."""

TRACK_STEPS = 30
"""Steps of each training frame's pose refinement that settles the pose track (:func:`track_steps`).
Adam's first steps move every coordinate by about the learning rate, whatever its gradient, so
the poses settle only after a few tens (docs/lab/defaults.md, "Fit: settling the pose track")."""

HELD_OUT_STEPS = 90
"""Steps that align each held-out frame's pose to its image once the avatar is finished
(:func:`held_out_steps`). A held-out frame starts from its neighbours' corrections, often pixels
off its image, and at the capture's learning rate is still moving after 30 steps: 90 score the
shared real video's held-out frames 0.7 dB higher for 10 s more (docs/lab/real-videos.md)."""

TRACK_FINE_STEPS = 10
"""The last of a frame's settling steps, which run the network at full resolution; the others are
coarse (:mod:`pghm.train.pose_refine`): half the resolution, the network's maps held, a third of the
time. Six leave the held-out frames a little worse aligned than a fully live settling, ten a little
better (docs/lab/fit-speed.md)."""

EARLY_TRACK_STEPS = 20
"""Coarse settling steps per training frame between the stages (:func:`early_track_steps`): stage 2
then learns the person's appearance from frames aligned to the stage-1 avatar rather than a few
pixels off, which sharpens it (docs/training.md, "The pose track")."""

TRACK_MIN_VISITS = 20
"""Stage 2 visits per training frame (its steps x images per step / training images) from which its
corrections need no settling (docs/lab/defaults.md, "Fit: settling the pose track")."""

FIT_SILHOUETTE_WEIGHT = 4.0
"""Default weight of the silhouette term when fitting (the prior trains with 1.0,
:data:`pghm.train.background.SILHOUETTE_WEIGHT`): stronger cuts the halo around the body
(docs/lab/defaults.md, "Fit: the silhouette weight")."""


STAGE1_COARSE = 1.0
"""Share of stage 1's steps at half the image resolution (:mod:`pghm.train.coarse`): all of them.
Stage 1 adapts the latent alone, the person's broad colours and shape, which half the pixels
show as well (docs/training.md, "Coarse to fine")."""
STAGE2_COARSE = 0.8
"""Share of stage 2's first steps at half the image resolution: what the avatar learns there at a
quarter of the pixels' cost, the last fifth of full-resolution steps sharpens (docs/training.md,
"Coarse to fine")."""
STAGE2_DECAY = 0.2
"""Share of stage 2's last steps over which its learning rates fall to zero
(:func:`pghm.train.loop.decay_factor`): the full-resolution steps, annealed, settle the network
and the latent where the constant rate left them jittering."""


def _fit_stage(steps: int, coarse: float = 0.0, decay: float = 0.0) -> LoopConfig:
    return LoopConfig(
        steps=steps,
        coarse=coarse,
        decay=decay,
        images_per_shard=2,
        loss=LossWeights(pose_prior=FIT_POSE_PRIOR, silhouette=FIT_SILHOUETTE_WEIGHT),
        background=TRAINING_BACKGROUND,
    )


@dataclass
class FitConfig:
    """Two-stage personalisation; defaults sized for a 2-core CPU (paper: 1k + 1k steps).

    50 + 450 steps stop where the prior's return on time falls off. Both stages train on a
    random background colour per image with the silhouette term (weight
    :data:`FIT_SILHOUETTE_WEIGHT`), so the avatar holds on any background (docs/lab/defaults.md,
    "Fit: steps and backgrounds").
    """

    stage1: LoopConfig = field(default_factory=lambda: _fit_stage(50, coarse=STAGE1_COARSE))
    stage2: LoopConfig = field(default_factory=lambda: _fit_stage(450, coarse=STAGE2_COARSE, decay=STAGE2_DECAY))
    latent_lr: float = 1e-2
    """Adam learning rate of the personal latent (both stages)."""
    network_lr: float = 2e-4
    """Adam learning rate of the U-Net in stage 2."""
    pose_lr: float | None = None
    """Adam learning rate of the per-frame pose corrections in stage 2 (lazy rows, as in the
    prior); None: :func:`pose_learning_rate` of the subject's stated pose noise."""
    refine_poses: bool = True
    pose_smoothing: float = 0.0
    """Standard deviation in frames of a Gaussian filter applied over time to the video's
    estimated poses before fitting (0: use them as stored); see :mod:`pghm.train.pose_smoothing`.
    Off by default: the per-frame corrections decide the result (docs/lab/defaults.md, "Fit:
    steps and backgrounds")."""
    track_steps: int | None = None
    """Steps of pose refinement per training frame after stage 2, the avatar frozen, that settle
    the pose track (:data:`TRACK_STEPS`); None: :func:`track_steps` of the subject's stated noise
    and of stage 2's visits per frame."""
    early_track_steps: int | None = None
    """Coarse steps of pose refinement per training frame between the stages, against the stage-1
    avatar (:data:`EARLY_TRACK_STEPS`); None: :func:`early_track_steps` of the subject's stated noise."""
    held_out_steps: int | None = None
    """Steps of pose refinement per frame held out of training, once the avatar is finished, that
    align it to its own image (:func:`align_held_out`); None: :func:`held_out_steps` of the
    subject's stated noise."""
    uv_resolution: int | None = None
    """L of the avatar's UV maps; None: the prior's. Another L carries the prior's weights over
    (:meth:`PGHM.at_resolution`): (L / L_prior)^2 times as many Gaussians, finer detail, longer
    fits and slower viewing (docs/training.md, "Resolution, steps and image size")."""
    detail: LoopConfig = field(default_factory=lambda: _fit_stage(DETAIL_STEPS))
    """The detail stage (:mod:`pghm.train.detail`); 0 steps: no detail layer, the paper's model
    (docs/training.md, "Detail layer")."""
    detail_validation: int = VALIDATION_EVERY
    """Every this-many training frames, one is held out of the detail stage, and the layer is kept
    only if it draws those frames closer than the avatar without it (:mod:`pghm.train.detail`);
    0: the layer is trained on every frame and kept."""
    detail_lr: float = DETAIL_LR
    """Adam learning rate of the detail layer's residuals."""
    split: str = "train"
    """The subject's split the avatar is fitted on (:data:`pghm.subject.ALL_SPLIT`: every
    image, as ``pghm capture --polish`` does to align the held-out frames' poses)."""
    track_fine_steps: int = TRACK_FINE_STEPS
    """Of the settling's steps per frame, the last ones that run the network at full resolution
    (:data:`TRACK_FINE_STEPS`); the others are coarse. The settling scores the dynamic render alone,
    the one the avatar is shown with."""
    hold_appearance: bool = False
    """Settle the pose track with the network's maps held at each batch's starting poses at every
    step (:class:`pghm.train.pose_refine.HeldAppearance`): no U-Net runs per step; off, as it aligns
    worse (docs/training.md, "Speed")."""
    crop_margin: int | None = CROP_MARGIN
    """Train on each image cut to the person's box with this margin in pixels, the loss kept the
    full frame's (:mod:`pghm.train.person_crop`); None: whole frames."""
    lpips: bool = True
    body_model_path: str | None = None
    precision: str = "auto"
    """What the networks compute in (:func:`pghm.device.resolve_precision`): "auto" is bfloat16 on a
    CPU that multiplies it natively, where a step is cheaper at the same held-out figures, else
    float32 (docs/training.md, "bfloat16 where the CPU multiplies it natively"). The avatar's
    weights are float32 either way."""
    minutes: float | None = None
    """A wall-clock budget for the whole fit: the phases are sized to it on the machine as it runs
    (:mod:`pghm.train.plan`), so the avatar depends on the machine's speed; None: the config's steps."""


GPU_CANDIDATE_RESOLUTION = 256
"""UV side L of :func:`gpu_fit_candidate`."""
GPU_CANDIDATE_STEPS = (200, 2000)
"""Stage 1 and stage 2 steps of :func:`gpu_fit_candidate`."""
GPU_CANDIDATE_IMAGES = 4
"""Images per step of :func:`gpu_fit_candidate`."""


def gpu_fit_candidate() -> FitConfig:
    """A fit sized for one GPU and about two minutes, NOT MEASURED: no command uses it by default.

    The CPU defaults (:class:`FitConfig`) stay every command's defaults on every device.
    ``benchmarks/bench_gpu.py`` fits with this configuration on a CUDA device and scores it
    against the CPU default fit, with steps per second at L = 128, 256 and 512; until it has
    run on a GPU these numbers are a guess from the U-Net's step time on one GPU (about 20 ms),
    not a tuned choice.
    """
    config = FitConfig(uv_resolution=GPU_CANDIDATE_RESOLUTION)
    for name, steps in zip(("stage1", "stage2"), GPU_CANDIDATE_STEPS):
        stage = replace(getattr(config, name), steps=steps, images_per_shard=GPU_CANDIDATE_IMAGES)
        setattr(config, name, stage)
    return config


def pose_learning_rate(rotation_sigma: float) -> float:
    """The default learning rate of the pose corrections for poses stated ``rotation_sigma`` (radians) noisy:

        lr = POSE_LR * min(1, sigma_0 / sigma),    sigma_0 = ESTIMATOR_ROTATION_SIGMA (2 degrees).

    Adam moves a correction by about its learning rate at each of a frame's few visits (about
    ten in 450 steps) whatever the gradient, and what pulls the coordinates an image barely
    sees back is the Gaussian prior on the corrections, whose pull falls as 1 / sigma^2. A
    capture states 9.5 degrees, so the same rate would let its corrections wander with the
    gradients' noise; the synthetic subjects (2 degrees) keep the rate they were tuned at
    (docs/lab/defaults.md, "Fit: the pose corrections' learning rate").
    """
    return POSE_LR * min(1.0, ESTIMATOR_ROTATION_SIGMA / rotation_sigma)


def stated_noisy(rotation_sigma: float) -> bool:
    """Whether poses stated ``rotation_sigma`` radians noisy are noisier than the synthetic data's
    (2 degrees): a capture's, whose fit settles and aligns its poses by default."""
    return rotation_sigma > ESTIMATOR_ROTATION_SIGMA


def track_steps(rotation_sigma: float, visits: float, early_steps: int) -> int:
    """The default steps that settle the pose track after stage 2: :data:`TRACK_STEPS` for poses
    stated noisier than the synthetic data's (:func:`stated_noisy`: a capture's) whose frames stage 2
    visits fewer than :data:`TRACK_MIN_VISITS` times each (``visits``) and that were not settled
    between the stages (``early_steps`` 0), else 0. A synthetic subject's corrections are within
    stage 2's reach (the shipped avatar is unchanged), and so are those of a short video; a track
    settled between the stages ends as well aligned without it (docs/training.md, "The pose track")."""
    if early_steps:
        return 0
    return TRACK_STEPS if stated_noisy(rotation_sigma) and visits < TRACK_MIN_VISITS else 0


def early_track_steps(rotation_sigma: float) -> int:
    """The default coarse steps that settle the training frames' poses between the stages:
    :data:`EARLY_TRACK_STEPS` for poses stated noisier than the synthetic data's (a capture's), else 0."""
    return EARLY_TRACK_STEPS if stated_noisy(rotation_sigma) else 0


def held_out_steps(rotation_sigma: float) -> int:
    """The default steps that align the held-out frames' poses: :data:`HELD_OUT_STEPS` for poses stated
    noisier than the synthetic data's (a capture's), else 0. A capture's estimates are a few pixels
    off, which no interpolation of the training frames' corrections fixes (their errors change from
    frame to frame); a synthetic subject's are not."""
    return HELD_OUT_STEPS if stated_noisy(rotation_sigma) else 0


def settle(
    avatar: Avatar,
    data: TrainingData,
    corrections: PoseCorrections,
    config: FitConfig,
    steps: int,
    fine_steps: int,
    what: str,
    images: list[int] | None = None,
) -> None:
    """The fit's settling pass: ``corrections``' rows of the frames of ``data`` (or of its
    ``images``) refined against their images for ``steps`` steps, all but the last ``fine_steps``
    coarse, ``avatar`` frozen (:func:`pghm.train.pose_refine.refine_poses`: the fit's loss on the
    dynamic render, the rate of poses as noisy as the synthetic data's, a batch of frames per core)."""
    refine_poses(
        avatar,
        data,
        steps,
        config.stage2.loss,
        POSE_LR,
        corrections,
        images=images,
        body_model_path=config.body_model_path,
        progress=config.stage2.progress,
        desc=f"fit: {what}",
        hold_appearance=config.hold_appearance,
        coarse_steps=max(steps - fine_steps, 0),
        dynamic_only=True,
        workers=torch.get_num_threads(),
    )


def align_held_out(avatar: Avatar, subject_dir: str | Path, config: FitConfig, steps: int) -> PoseTrack:
    """The avatar's pose track extended to every frame of its subject it was not trained on, each
    aligned to its own image for ``steps`` steps, the avatar frozen.

    A held-out frame starts from the training frames' corrections interpolated onto it
    (:func:`pghm.train.pose_track.track_corrections`) and is refined as the fit settles its
    training frames: coarse to fine, the dynamic render's loss, a batch of frames per core. Its
    image moves its pose only: the avatar's weights are those the training frames gave (tested).
    The track lists these frames in :attr:`PoseTrack.aligned`, and ``pghm eval --fit-poses``
    reports them, since their poses have seen their images.
    """
    data = TrainingData(subject_dir, split=ALL_SPLIT, crop_margin=config.crop_margin)
    images = np.asarray(data.images[0], dtype=np.int64)
    frames = frame_numbers(data, images)
    held = ~np.isin(frames, avatar.pose_track.frames.numpy())
    if not held.any() or not steps:
        return avatar.pose_track
    corrections, _ = track_corrections(avatar.pose_track, data, load_body(data.body_name, config.body_model_path))
    corrections = corrections.to(avatar.device)
    held_images = images[held].tolist()
    settle(avatar, data, corrections, config, steps, config.track_fine_steps, "align held-out poses", held_images)
    aligned = torch.as_tensor(np.unique(frames[held]), dtype=torch.int64)
    return replace(learned_track(corrections, data), aligned=aligned)


def add_detail(
    avatar: Avatar,
    data: TrainingData,
    corrections: PoseCorrections | None,
    config: FitConfig,
    lpips: nn.Module | None,
    budget: Budget | None = None,
) -> dict:
    """Train a detail layer on the finished ``avatar`` and give it to the avatar if it validates
    (:mod:`pghm.train.detail`); returns the decision and its figures, which go to the avatar's metadata."""
    images = [int(i) for i in data.images[0]]
    held = validation_images(images, config.detail_validation)
    detail = config.detail if budget is None else replace(config.detail, steps=budget.phases[DETAIL].steps)
    model, state, record = validated_detail(
        avatar, data, held, corrections, detail, config.detail_lr, lpips, config.body_model_path, budget
    )
    avatar.metadata["steps"]["detail"] = state.step
    record["seconds"] = round(state.seconds, 1)
    if held:
        verdict = "kept" if record["kept"] else "dropped"
        log.info(
            "fit: detail layer %s after %d steps: squared error of %d held frames %.1f with it, %.1f without",
            verdict,
            state.step,
            len(held),
            record["error_with"],
            record["error_without"],
        )
    if model is not None:
        avatar.model = model
    avatar.metadata["detail"] = record
    return record


def detail_refusal(config: FitConfig, data: TrainingData) -> str | None:
    """Why the fit trains no detail layer for ``data``, or None when it does."""
    if not config.detail.steps:
        return "--detail-steps 0"
    images = len(data.images[0])
    held = validation_images(range(images), config.detail_validation)
    if config.detail_validation and len(held) < MIN_VALIDATION_IMAGES:
        return f"{images} training images: too few to validate a layer"
    return None


def initial_latent(model: PGHM) -> torch.Tensor:
    """(1, C, L, L) on the model's device: the decoded mean of the bank's latents (a fresh latent
    for an empty bank)."""
    with torch.no_grad():
        if model.num_identities == 0:
            size = model.config.uv_resolution
            return torch.zeros(1, model.config.latent_channels, size, size, device=model.identity_bank.device)
        return model.decode_latent(model.identity_bank.mean(0, keepdim=True))


def network_parameters(model: PGHM) -> list[nn.Parameter]:
    return [p for part in NETWORK_PARTS if hasattr(model, part) for p in getattr(model, part).parameters()]


def _checkpoint_stage(payload: dict, path: Path) -> int:
    """The stage (1 or 2) a fit checkpoint was saved in; PghmError for another command's checkpoint."""
    extra = payload.get("extra")
    stage = extra.get("stage") if isinstance(extra, dict) else None
    if stage == 3:
        raise PghmError(f"{path}: a checkpoint of the detail stage, which does not resume; run the fit again")
    if type(stage) is not int or stage not in (1, 2):
        raise PghmError(f"{path}: not a checkpoint of pghm fit (from train-prior?); cannot --resume from it")
    return stage


@dataclass
class FitRun:
    """What a fit's phases share and change: the config with its defaults resolved, the data, the
    model with its personal latent and pose corrections, the objective, and the checkpoint."""

    config: FitConfig
    subject_dir: Path
    out: Path
    checkpoint: Path
    data: TrainingData
    model: PGHM
    latent: nn.Parameter
    corrections: PoseCorrections | None
    objective: AvatarObjective
    geometries: GeometryCache
    lpips: nn.Module | None
    lpips_line: str
    prior_source: str
    held_out_images: int
    payload: dict | None
    start_stage: int
    states: dict[str, LoopState] = field(default_factory=dict)
    avatar: Avatar | None = None

    @property
    def settles_poses(self) -> bool:
        """Whether the phases after stage 2 refine the pose track: corrections of smoothed poses
        would not apply to the held-out frames' stored ones."""
        return self.corrections is not None and not self.config.pose_smoothing


def resolved(config: FitConfig, data: TrainingData) -> FitConfig:
    """``config`` with every default that depends on the subject resolved, its values checked."""
    for name in ("track_steps", "early_track_steps", "held_out_steps"):
        if getattr(config, name) is not None and getattr(config, name) < 0:
            raise PghmError(f"{name} must be >= 0, got {getattr(config, name)}")
    for name in ("track_fine_steps", "detail_validation"):
        if getattr(config, name) < 0:
            raise PghmError(f"{name} must be >= 0, got {getattr(config, name)}")
    for name in ("latent_lr", "network_lr", "pose_lr", "detail_lr"):
        if getattr(config, name) is not None:
            check_learning_rate(name, getattr(config, name))
    if config.minutes is not None and not (math.isfinite(config.minutes) and config.minutes > 0):
        raise PghmError(f"minutes must be a positive number, got {config.minutes}")
    sigma = data.pose_noise[0][0]
    if config.pose_lr is None:
        config = replace(config, pose_lr=pose_learning_rate(sigma))
    if config.held_out_steps is None:
        config = replace(config, held_out_steps=held_out_steps(sigma))
    if config.early_track_steps is None:
        config = replace(config, early_track_steps=early_track_steps(sigma))
    if config.track_steps is None:
        stage2 = config.stage2
        visits = stage2.steps * stage2.images_per_shard * stage2.shards / max(len(data.images[0]), 1)
        config = replace(config, track_steps=track_steps(sigma, visits, config.early_track_steps))
    return config


def prepare(
    subject_dir: str | Path,
    prior: str | Path | Avatar | ModelConfig,
    out: Path,
    config: FitConfig,
    resume: bool,
    device: torch.device,
) -> FitRun:
    """Everything a fit's phases need, read and checked before the first step."""
    ckpt = checkpoint_path(out, resume)
    data = TrainingData(
        subject_dir, split=config.split, pose_smoothing=config.pose_smoothing, crop_margin=config.crop_margin
    )
    if data.num_identities != 1:
        raise PghmError(f"{subject_dir}: fit takes one subject folder, found {data.num_identities}")
    config = resolved(config, data)
    if config.uv_resolution is not None:  # before a model is built at it (minutes at the largest L)
        _check_detail_resolution(config, data, config.uv_resolution)
    check_step_memory(data, config.stage1, "fit stage 1")
    check_step_memory(data, config.stage2, "fit stage 2")
    check_step_memory(data, config.detail, "fit detail stage")
    if isinstance(prior, ModelConfig):
        torch.manual_seed(config.stage1.seed)
        if config.uv_resolution is not None:
            prior = replace(prior, uv_resolution=config.uv_resolution)
        model, prior_source = PGHM(prior, num_identities=0), "none (from scratch)"
    else:
        prior_avatar = prior if isinstance(prior, Avatar) else load_avatar(prior)
        if prior_avatar.kind != "prior":
            raise PghmError(f"{prior}: is a personalised avatar, not a prior (pghm train-prior); fit needs a prior")
        data.check_body(prior_avatar.body_name, prior if not isinstance(prior, Avatar) else "the prior")
        model = prior_avatar.model
        if config.uv_resolution not in (None, model.config.uv_resolution):
            model = model.at_resolution(config.uv_resolution)
        prior_source = recorded_path(prior) if not isinstance(prior, Avatar) else "(in memory)"
    if config.uv_resolution is None:  # the prior's own L (a given one was checked above)
        _check_detail_resolution(config, data, model.config.uv_resolution)
    model = model.to(device).set_precision(resolve_precision(config.precision, device))
    model.train()
    for p in model.parameters():
        p.requires_grad_(False)
    geometries = GeometryCache(data, model.config, config.body_model_path, device)
    latent = nn.Parameter(initial_latent(model))
    corrections = data.pose_corrections(geometries.body).to(device) if config.refine_poses else None
    check_output_room(out, model, *([corrections] if corrections is not None else []))
    lpips, lpips_line = lpips_for(config.lpips, device)
    payload = load_checkpoint(ckpt) if resume else None
    subject_images = len(data.subjects[0].split(ALL_SPLIT).indices)
    objective = AvatarObjective(model, latent, corrections, config.stage1.loss, lpips)
    if payload:  # a diverged or foreign checkpoint refused before the plan is shown, not when its stage starts
        restore_objective(payload, objective)
    return FitRun(
        config=config,
        subject_dir=Path(subject_dir),
        out=out,
        checkpoint=ckpt,
        data=data,
        model=model,
        latent=latent,
        corrections=corrections,
        objective=objective,
        geometries=geometries,
        lpips=lpips,
        lpips_line=lpips_line,
        prior_source=prior_source,
        held_out_images=max(subject_images - len(data.images[0]), 0),
        payload=payload,
        start_stage=_checkpoint_stage(payload, ckpt) if payload else 1,
    )


def _check_detail_resolution(config: FitConfig, data: TrainingData, resolution: int) -> None:
    """Refuse a detail layer whose atlas, at twice ``resolution``, would pass the largest there is."""
    if detail_refusal(config, data) is None and DETAIL_FACTOR * resolution > MAX_RESOLUTION:
        raise PghmError(
            f"a detail layer needs {DETAIL_FACTOR}L <= {MAX_RESOLUTION}, L is {resolution}: "
            "give a smaller --uv-resolution or --detail-steps 0"
        )


def fit_phases(run: FitRun) -> list[Phase]:
    """The fit's plan at its config's steps: every phase of :data:`pghm.train.plan.PHASES`, 0 steps
    for those this subject and config leave out."""
    config, training = run.config, len(run.data.images[0])
    poses = run.corrections is not None
    return [
        Phase(STAGE1, config.stage1.steps, coarse=config.stage1.coarse),
        Phase(EARLY_SETTLING, config.early_track_steps if poses else 0, training),
        Phase(STAGE2, config.stage2.steps, coarse=config.stage2.coarse),
        Phase(POSE_SETTLING, config.track_steps if run.settles_poses else 0, training),
        Phase(HELD_OUT, config.held_out_steps if run.settles_poses else 0, run.held_out_images),
        Phase(DETAIL, 0 if detail_refusal(config, run.data) else config.detail.steps),
    ]


def _stage(run: FitRun, budget: Budget, number: int) -> dict:
    """Stage 1 (the latent alone) or stage 2 (latent, network and pose corrections together)."""
    name, config = (STAGE1, run.config.stage1) if number == 1 else (STAGE2, run.config.stage2)
    if number == 1:
        optimizer = torch.optim.Adam([run.latent], lr=run.config.latent_lr)
        trainable = [run.latent]
    else:
        network = network_parameters(run.model)
        for p in network:
            p.requires_grad_(True)
        groups = [
            {"params": [run.latent], "lr": run.config.latent_lr},
            {"params": network, "lr": run.config.network_lr},
        ]
        if run.corrections is not None:
            groups.append({"params": list(run.corrections.parameters()), "lr": run.config.pose_lr, "lazy": True})
            run.corrections.requires_grad_(True)
        optimizer, trainable = LazyAdam(groups), [p for g in groups for p in g["params"]]
        run.objective.weights = config.loss
    state = LoopState()
    if run.payload and run.start_stage == number:
        state = restore(run.payload, run.objective, optimizer)
    budget.start(name, state.step)
    state = run_stage(
        objective=run.objective,
        trainable=trainable,
        optimizer=optimizer,
        data=run.data,
        geometry_of=run.geometries,
        config=config,
        checkpoint=run.checkpoint,
        state=state,
        extra={"stage": number},
        description=f"fit {number}/2",
        budget=budget,
    )
    run.states[name] = state
    every = config.checkpoint_every
    if state.history and not (every and state.step % every == 0):  # history: a step saw an image
        # The stage's end, unless its last step has just saved it: a fit interrupted in a later
        # phase resumes from here, the stage done, and runs the phases after it as they would have run.
        save_checkpoint(run.checkpoint, run.objective, optimizer, state, {"stage": number})
    return {"psnr": state.history[-1]["psnr"]} if state.history else {}


def _early_settling(run: FitRun, budget: Budget) -> dict:
    """Every training frame's pose settled coarsely against the stage-1 avatar."""
    steps = budget.start(EARLY_SETTLING).steps
    stage1 = Avatar(run.model, "avatar", run.data.body_name, run.data.shape(0), latent=run.latent.detach())
    settle(stage1, run.data, run.corrections, run.config, steps, 0, "settle poses on the stage-1 avatar")
    run.model.train()
    budget.progress(steps * len(run.data.images[0]))
    return {}


def finished_avatar(run: FitRun) -> Avatar:
    """The avatar the two stages made, with the fit's record; refused if the stages trained on nothing."""
    # A stage not run this time: resumed past stage 1 (its steps done), or planned at 0 steps.
    state1 = run.states.get(STAGE1, LoopState(step=run.config.stage1.steps if run.start_stage > 1 else 0))
    state2 = run.states.get(STAGE2, LoopState())
    avatar = Avatar(
        model=run.model.eval(),
        kind="avatar",
        body_name=run.data.body_name,
        shape=run.data.shape(0),
        latent=run.latent.detach().clone(),
        metadata={
            "command": "fit",
            "data": recorded_path(run.subject_dir),
            "prior": run.prior_source,
            "prior_identities": run.model.num_identities,
            "training_images": int(len(run.data.images[0])),
            "steps": {"stage1": state1.step, "stage2": state2.step},
            "seconds": round(state1.seconds + state2.seconds, 1),
            "threads": torch.get_num_threads(),  # the last bits of every float depend on it
            "precision": str(run.model.compute_dtype).removeprefix("torch."),
            "skipped_steps": state1.skipped_steps + state2.skipped_steps,
            "skipped_images": [list(b) for b in state2.bad_images],
            "lpips": run.lpips_line,
            "final": state2.history[-1] if state2.history else {},
            "config": config_record(run.config),
        },
    )
    for p in run.model.parameters():
        p.requires_grad_(True)
    check_trained([state1, state2], run.out)  # before settling: no minutes spent on a failed fit
    if run.settles_poses:
        avatar.pose_track = move(learned_track(run.corrections, run.data), torch.device("cpu"))  # as in the file
    return avatar


def _pose_settling(run: FitRun, budget: Budget) -> dict:
    """Every training frame's correction refined against its image, the avatar frozen."""
    steps = budget.start(POSE_SETTLING).steps
    settle(run.avatar, run.data, run.corrections, run.config, steps, run.config.track_fine_steps, "settle poses")
    run.avatar.pose_track = move(learned_track(run.corrections, run.data), torch.device("cpu"))
    budget.progress(steps * len(run.data.images[0]))
    return {}


def _held_out(run: FitRun, budget: Budget) -> dict:
    """The frames held out of training aligned to their own images (:func:`align_held_out`)."""
    steps = budget.start(HELD_OUT).steps
    track = align_held_out(run.avatar, run.subject_dir, run.config, steps)
    run.avatar.pose_track = move(track, torch.device("cpu"))
    budget.progress(steps * run.held_out_images)
    return {"frames": len(run.avatar.pose_track.aligned)}


def _detail(run: FitRun, budget: Budget) -> dict:
    budget.start(DETAIL)
    record = add_detail(run.avatar, run.data, run.corrections, run.config, run.lpips, budget)
    return {"kept": record["kept"]}


def fit(
    subject_dir: str | Path,
    prior: str | Path | Avatar | ModelConfig,
    out: str | Path,
    config: FitConfig | None = None,
    resume: bool = False,
    device: torch.device | str = "cpu",
    outputs: Outputs | None = None,
) -> Avatar:
    """Personalise ``prior`` to the subject in ``subject_dir`` and save the avatar to ``out``: the
    phases of :func:`fit_phases` in order, each sized by the plan (:mod:`pghm.train.plan`; with
    ``config.minutes``, to that wall-clock budget).

    Args:
        prior: a prior file or loaded prior; or a :class:`ModelConfig` to train the same
            model from scratch (random network, latent from zero) for comparison.
        device: where the model, data and optimiser live; the avatar is written from the CPU.
        outputs: the command's outputs, when the avatar is one of several that appear together
            (:func:`pghm.io.atomic.all_or_none`); the checkpoint is removed once they do.
    """
    started = time.perf_counter()  # a budget counts the set-up too: it is the command's wall time
    run = prepare(subject_dir, prior, Path(out), config or FitConfig(), resume, torch.device(device))
    minutes = run.config.minutes
    budget = Budget(fit_phases(run), None if minutes is None else 60 * minutes, started=started)
    log.info("fit plan%s:\n%s", f" for {minutes:g} min" if minutes else "", describe(budget.plan(), budget.costs))
    phases = {
        STAGE1: lambda: _stage(run, budget, 1),
        EARLY_SETTLING: lambda: _early_settling(run, budget),
        STAGE2: lambda: _stage(run, budget, 2),
        POSE_SETTLING: lambda: _pose_settling(run, budget),
        HELD_OUT: lambda: _held_out(run, budget),
        DETAIL: lambda: _detail(run, budget),
    }
    for name, phase in phases.items():
        if name == POSE_SETTLING:
            run.avatar = finished_avatar(run)
        if name in (STAGE1, EARLY_SETTLING) and run.start_stage > 1:
            budget.skip(name, "resumed in stage 2")
        elif not budget.phases[name].steps:
            budget.skip(name, "not planned")
            if name == DETAIL and run.config.detail.steps:
                why = detail_refusal(run.config, run.data) or "no time left in the budget"
                run.avatar.metadata["detail"] = {"kept": False, "why": why}
        else:
            with profile.phase(name), _interrupted_after_a_stage(name, run.checkpoint):
                budget.finish(phase())
                interrupt_point(f"fit {name}")  # a test hook: a signal once the phase's work is done
            if name == STAGE1:
                log.info("fit: stage 1 done; the rest of the plan:\n%s", describe(budget.remaining(), budget.costs))
    record_plan(run.avatar, budget)
    run.avatar.model.set_precision(torch.float32)  # the avatar as its file holds it
    with profile.phase("save"):
        save_avatar(run.out, run.avatar, outputs)
    # The avatar holds the result; a stale checkpoint would only mislead --resume.
    forget_checkpoint = lambda: run.checkpoint.unlink(missing_ok=True)
    if outputs is None:
        forget_checkpoint()
    else:
        outputs.after.append(forget_checkpoint)
    return run.avatar


@contextlib.contextmanager
def _interrupted_after_a_stage(name: str, checkpoint: Path) -> Iterator[None]:
    """Ctrl-C or SIGTERM in a phase after a stage: say where the fit resumes from (the last stage's
    end, which :func:`_stage` saved), as the stages' own interruptions do."""
    try:
        yield
    except KeyboardInterrupt:
        if name not in (STAGE1, STAGE2) and checkpoint.is_file():
            print(f"interrupted in {name}: checkpoint saved to {checkpoint}; continue with --resume", file=sys.stderr)
        raise


def record_plan(avatar: Avatar, budget: Budget) -> None:
    """The plan's record in the avatar's metadata: per phase its steps, seconds and what it bought;
    the budget, if any; and the settling phases' seconds under the names the metadata always had."""
    avatar.metadata["plan"] = {name: budget.records[name] for name in budget.order if name in budget.records}
    if budget.deadline is not None:
        avatar.metadata["budget_seconds"] = round(budget.deadline - budget.started, 1)
        avatar.metadata["fit_seconds"] = round(budget.elapsed(), 1)
    seconds_keys = {EARLY_SETTLING: "early_track_seconds", POSE_SETTLING: "track_seconds", HELD_OUT: "held_out_seconds"}
    for name, key in seconds_keys.items():
        if budget.records.get(name, {}).get("steps"):
            avatar.metadata[key] = budget.records[name]["seconds"]
    if HELD_OUT in budget.records and budget.records[HELD_OUT].get("steps"):
        avatar.metadata["held_out_frames"] = budget.records[HELD_OUT]["frames"]
