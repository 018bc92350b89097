"""Pose refinement against a frozen avatar: each frame's pose fitted to its own image.

A monocular capture's poses carry its estimator's error. ``pghm fit`` corrects the poses of the
frames it trains on (per-frame corrections in stage 2), but a held-out frame keeps its estimate,
and an estimate a few pixels off leaves an error along every edge of the render: PSNR then
measures the pose estimator, not the avatar. Evaluations of monocular avatars therefore refine
the held-out poses against their images with the model frozen (InstantAvatar and GART on
PeopleSnapshot); ``pghm fit`` uses the same pass on its *training* frames to settle its pose
track once the avatar is learned (:mod:`pghm.train.pose_track`). Both use the fit's objective:

    delta* = argmin_delta  L(render(avatar, pose + delta), image) + w_p P(delta)

L is the fit's loss (L1 + SSIM + silhouette, on a random background colour per image and
step), P the fit's Gaussian prior on the corrections (:meth:`PoseCorrections.prior`, as wide
as the subject's stated pose noise) with its weight w_p; only delta changes (the estimator's
joints and the root translation, one row per frame). A frame's row depends on its image
alone, so the frames are refined a batch at a time, each batch for all its steps (lazy Adam
rows: a batch's steps leave the other frames' rows and moments untouched), and only one batch
of images is in memory. Appearance is untouched: the latent and every network weight stay as
fitted.
"""

from __future__ import annotations

import logging

import torch
from torch import Tensor
from tqdm import tqdm

from pghm.body import load_body
from pghm.body.pose import BodyPose
from pghm.io.avatar import Avatar, avatar_geometry
from pghm.model.geometry import SubjectGeometry
from pghm.model.pghm import AvatarOutput, IdentityFeatures, PoseBranch
from pghm.train import profile
from pghm.train.background import TRAINING_BACKGROUND, draw_backgrounds
from pghm.train.data import PoseCorrections, TrainingData
from pghm.train.loop import AvatarObjective
from pghm.train.losses import LossWeights
from pghm.train.optim import LazyAdam

log = logging.getLogger(__name__)

IMAGES_PER_BATCH = 2
"""Images rendered together in one forward pass (the fit's batch): memory, not the result."""
REFINE_SEED_SALT = 0x7E57
"""Keeps the refinement's background draws apart from the fit's (same seed, same step)."""


class HeldAppearance(AvatarObjective):
    """The objective with the network's maps held at a batch's starting poses.

    A pose correction then moves the Gaussians through the skinning alone: offsets, scales and
    colours stay those the network gave the starting pose, as for a pose change too small to
    change them. A step costs the skinning, the splatter and the loss, not the U-Net forward
    and backward. :meth:`release` drops the held maps (a new batch of frames).
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._features: IdentityFeatures | None = None
        self._held: tuple[PoseBranch, Tensor] | None = None

    def release(self) -> None:
        self._held = None

    def avatar(
        self, identity: int, geometry: SubjectGeometry, pose: BodyPose, centres: Tensor, pose_index: Tensor
    ) -> AvatarOutput:
        model = self.model
        skinned = model.skin(geometry, pose)
        if self._held is None:
            with torch.no_grad():
                if self._features is None:
                    self._features = model.identity_features(self.identity_map(identity))
                branch = model.pose_branch(self._features, skinned).select(pose_index)
                view = model.view_branch(self._features, skinned.select(pose_index), branch, geometry, centres)
            self._held = (branch, view)
        branch, view = self._held
        return model.assemble(self._features, skinned.select(pose_index), branch, view, geometry)


def refine_poses(
    avatar: Avatar,
    data: TrainingData,
    steps: int,
    weights: LossWeights,
    lr: float,
    corrections: PoseCorrections | None = None,
    images: list[int] | None = None,
    body_model_path: str | None = None,
    seed: int = 0,
    progress: bool = True,
    desc: str = "refine poses",
    batch: int = IMAGES_PER_BATCH,
    hold_appearance: bool = False,
) -> PoseCorrections:
    """Pose corrections of the frames of ``data`` (one subject) fitted to their images for
    ``steps`` Adam steps (learning rate ``lr``, loss ``weights``), ``avatar`` frozen.

    ``corrections``: where to start (updated in place; None: zero corrections of every frame).
    ``images``: only these image indices of ``data`` (None: all of them). ``batch``: images
    refined together. ``hold_appearance``: the network's maps held at each batch's starting
    poses (:class:`HeldAppearance`). Returns the corrections, indexed by
    :attr:`Sample.frame_key`; the other frames' rows are unchanged.
    """
    body = load_body(avatar.body_name, body_model_path)
    geometry = avatar_geometry(avatar, body_model_path=body_model_path)
    corrections = data.pose_corrections(body).to(avatar.device) if corrections is None else corrections
    corrections.requires_grad_(True)
    model = avatar.model.eval()
    frozen = [p for p in model.parameters() if p.requires_grad]
    for p in frozen:
        p.requires_grad_(False)
    kind = HeldAppearance if hold_appearance else AvatarObjective
    objective = kind(model, avatar.identity_map(), corrections, weights, lpips=None)
    optimizer = LazyAdam([{"params": list(corrections.parameters()), "lr": lr, "lazy": True}])
    images = [int(i) for i in (data.images[0] if images is None else images)]
    starts = range(0, len(images), batch)
    bar = tqdm(total=len(starts) * steps, desc=desc, disable=not progress, dynamic_ncols=True)
    try:
        for position, start in enumerate(starts):
            with profile.part(profile.DATA):
                samples = data.load_group(0, images[start : start + batch])
            if hold_appearance:
                objective.release()
            if not samples:
                bar.update(steps)
                continue
            height, width = samples[0].camera.height, samples[0].camera.width
            for step in range(steps):
                optimizer.zero_grad(set_to_none=False)
                with profile.part(profile.DATA):
                    backgrounds = draw_backgrounds(
                        TRAINING_BACKGROUND, len(samples), height, width, (seed, REFINE_SEED_SALT, step, position)
                    )
                loss, _ = objective(samples, geometry, backgrounds)
                with profile.part(profile.LOSSES_BACKWARD):
                    loss.backward()
                bar.update(1)
                with profile.part(profile.GUARD):
                    finite = all(bool(torch.isfinite(p.grad).all()) for p in corrections.parameters())
                if not finite:
                    log.warning(
                        "pose refinement, images %s, step %d: non-finite gradient; step skipped",
                        [s.image_index for s in samples],
                        step,
                    )
                    continue
                with profile.part(profile.OPTIMISER):
                    optimizer.step()
    finally:
        bar.close()
        for p in frozen:
            p.requires_grad_(True)
    return corrections.requires_grad_(False)
