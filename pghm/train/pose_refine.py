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

Coarse to fine (``coarse_steps``, the fit's settling): a frame's first steps render at half the
image's resolution (:func:`pghm.train.coarse.coarse_samples`; a small image keeps its own) with the network's maps
held at the batch's starting poses (:class:`HeldAppearance`), which costs the skinning, the
splatter and the loss and no U-Net; its last steps run the network at full resolution, so the
poses end aligned as a fully live pass aligns them (docs/training.md, "Speed").
"""

from __future__ import annotations

import logging
import multiprocessing
import sys
from collections.abc import Callable
from multiprocessing.connection import Connection
from multiprocessing.sharedctypes import Synchronized

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from pghm.body import load_body
from pghm.body.pose import BodyPose
from pghm.errors import PghmError
from pghm.io.avatar import Avatar, avatar_geometry
from pghm.model.geometry import SubjectGeometry
from pghm.model.pghm import AvatarOutput, IdentityFeatures, PoseBranch
from pghm.train import profile
from pghm.train.background import TRAINING_BACKGROUND, draw_backgrounds
from pghm.train.coarse import coarse_samples
from pghm.train.data import PoseCorrections, Sample, TrainingData
from pghm.train.loop import AvatarObjective, all_finite
from pghm.train.losses import LossWeights
from pghm.train.optim import LazyAdam
from pghm.train.pose_track import frame_numbers

log = logging.getLogger(__name__)

IMAGES_PER_BATCH = 2
"""Images rendered together in one forward pass (the fit's batch): memory, not the result."""
REFINE_SEED_SALT = 0x7E57
"""Keeps the refinement's background draws apart from the fit's (same seed, same step)."""
FORKS = sys.platform.startswith("linux")
"""Whether batches are refined side by side, in forked children that share the avatar and the images
(:func:`_side_by_side`): on Linux. Windows cannot fork, and macOS's system libraries do not promise a
working child after threads have run; there the batches are refined one after another."""


class HeldAppearance(AvatarObjective):
    """The objective of a frozen avatar: its identity's features computed once, and the network's
    maps optionally held at a batch's starting poses.

    The latent and the weights do not change, so E_u and D_static (:class:`IdentityFeatures`) are
    the same at every step and run once. With :attr:`holding`, a pose correction moves the Gaussians
    through the skinning alone: offsets, scales and colours stay those the network gave the starting
    pose (in float32, whatever the model computes in), as for a pose change too small to change
    them. A step then costs the skinning, the splatter and the loss, not the U-Net forward and
    backward. :meth:`release` drops the held maps (a new batch of frames).
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._features: IdentityFeatures | None = None
        """The identity's features as the model computes them (:meth:`PGHM.compute_context`)."""
        self._full_features: IdentityFeatures | None = None
        """The same in float32, which the held maps are computed from (the same in a float32 model)."""
        self._held: tuple[PoseBranch, Tensor] | None = None
        self.holding = False
        """True: the maps are held at the batch's starting poses; False: the network's at each step's
        poses, as :class:`AvatarObjective`'s."""

    def release(self) -> None:
        self._held = None

    def avatar(
        self, identity: int, geometry: SubjectGeometry, pose: BodyPose, centres: Tensor, pose_index: Tensor
    ) -> AvatarOutput:
        model = self.model
        if not self.holding:
            if self._features is None:
                with torch.no_grad(), model.compute_context():
                    self._features = model.identity_features(self.identity_map(identity))
            return model.posed(self._features, geometry, pose, centres, pose_index)
        skinned = model.skin(geometry, pose)
        if self._held is None:
            with torch.no_grad():
                if self._full_features is None:
                    self._full_features = model.identity_features(self.identity_map(identity))
                features = self._full_features
                branch = model.pose_branch(features, skinned).select(pose_index)
                view = model.view_branch(features, skinned.select(pose_index), branch, geometry, centres)
            self._held = (branch, view)
        branch, view = self._held
        return model.assemble(self._full_features, skinned.select(pose_index), branch, view, geometry)


def _one_view_per_frame(data: TrainingData, images: list[int]) -> bool:
    """Whether no two of ``images`` show one frame (a monocular video): then no two batches refine
    one row, and batches can be refined in any order, side by side."""
    return len(np.unique(frame_numbers(data, images))) == len(images)


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
    coarse_steps: int = 0,
    dynamic_only: bool = False,
    workers: int = 1,
) -> PoseCorrections:
    """Pose corrections of the frames of ``data`` (one subject) fitted to their images for
    ``steps`` Adam steps (learning rate ``lr``, loss ``weights``), ``avatar`` frozen.

    ``corrections``: where to start (updated in place; None: zero corrections of every frame).
    ``images``: only these image indices of ``data`` (None: all of them). ``batch``: images
    refined together. ``hold_appearance``: the network's maps held at each batch's starting
    poses (:class:`HeldAppearance`). ``coarse_steps``: the first steps of each batch coarse
    (module doc). ``dynamic_only``: the loss of the dynamic render alone
    (:class:`AvatarObjective`). ``workers``: processes that refine the batches side by side, each
    on one thread (:func:`_side_by_side`), when no two images show one frame and the avatar is on
    the CPU; a batch's result is the same whichever refines it. Returns the corrections, indexed by
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
    images = [int(i) for i in (data.images[0] if images is None else images)]
    batches = [images[start : start + batch] for start in range(0, len(images), batch)]
    side_by_side = FORKS and avatar.device.type == "cpu" and _one_view_per_frame(data, images)
    workers = max(1, min(workers, len(batches))) if side_by_side else 1
    bar = tqdm(total=len(batches) * steps, desc=desc, disable=not progress, dynamic_ncols=True)
    settling = _Settling(
        avatar, data, geometry, weights, lr, steps, seed, hold_appearance, coarse_steps, dynamic_only, bar.update
    )
    threads = torch.get_num_threads()
    try:
        if workers == 1:
            settling.run(corrections, batches, range(len(batches)))
        else:
            torch.set_num_threads(1)
            _side_by_side(settling, corrections, batches, workers, bar)
    finally:
        torch.set_num_threads(threads)
        bar.close()
        for p in frozen:
            p.requires_grad_(True)
    return corrections.requires_grad_(False)


def _side_by_side(
    settling: _Settling, corrections: PoseCorrections, batches: list[list[int]], workers: int, bar: tqdm
) -> None:
    """Refine ``batches`` in ``workers`` processes, each on one thread: this one and ``workers - 1``
    forked children, the k-th taking every ``workers``-th batch from the k-th, whose rows it sends
    back into ``corrections``; ``bar`` counts every process's steps.

    Processes, not threads: a step is hundreds of small operators, and two threads in one
    interpreter take turns at its lock between them, which idled a quarter of two cores
    (docs/lab/fit-speed.md). A forked child shares the avatar and the images with this process and
    refines its own copy of the corrections; a child that fails raises its error here, and one
    that is still running when this process fails is killed.
    """
    context = multiprocessing.get_context("fork")
    shares = [range(worker, len(batches), workers) for worker in range(workers)]
    children_steps = context.Value("q", 0)
    children = []
    try:
        for share in shares[1:]:
            receiver, sender = context.Pipe(duplex=False)
            child = context.Process(
                target=_child, args=(settling, corrections, batches, share, sender, children_steps), daemon=True
            )
            child.start()
            sender.close()
            children.append((child, receiver))
        settling.advance = _Tally(bar, children_steps).update
        settling.run(corrections, batches, shares[0])
        for child, receiver in children:
            try:
                failed, outcome = receiver.recv()
            except EOFError:
                child.join()
                raise PghmError(f"a settling process ended without its result (exit status {child.exitcode})") from None
            if failed:
                raise outcome
            keys, rotations, translation, cpu = outcome
            rows = torch.as_tensor(keys, dtype=torch.long, device=corrections.rotations.device)
            with torch.no_grad():
                corrections.rotations[rows] = torch.as_tensor(rotations).to(corrections.rotations)
                corrections.translation[rows] = torch.as_tensor(translation).to(corrections.translation)
            profile.add_cpu(cpu)
        settling.advance(0)
    finally:
        for child, receiver in children:
            receiver.close()
            if child.is_alive():
                child.kill()
            child.join()


def _child(
    settling: _Settling,
    corrections: PoseCorrections,
    batches: list[list[int]],
    share: range,
    sender: Connection,
    steps: Synchronized,
) -> None:
    """A forked settling process: refine ``share`` of ``batches`` on one thread, counting the steps
    into ``steps``, and send (failed, outcome): the rows refined and the process's CPU seconds per
    profile part, or the error."""
    torch.set_num_threads(1)
    settling.advance = _Count(steps).update
    try:
        with profile.forked() as record:
            keys = settling.run(corrections, batches, share)
        rows = torch.as_tensor(keys, dtype=torch.long)
        rotations = corrections.rotations.detach()[rows].numpy()
        translation = corrections.translation.detach()[rows].numpy()
        outcome = (False, (keys, rotations, translation, dict(record.cpu) if record is not None else {}))
    except BaseException as error:  # noqa: BLE001 - every failure is the parent's to raise
        outcome = (True, error)
    try:
        sender.send(outcome)
    except Exception:  # noqa: BLE001 - an error that does not pickle goes as its text
        sender.send((True, PghmError(f"settling failed: {type(outcome[1]).__name__}: {outcome[1]}")))
    sender.close()


class _Count:
    """A forked child's progress: its steps added to a counter the parent's bar reads."""

    def __init__(self, steps: Synchronized) -> None:
        self.steps = steps

    def update(self, n: int) -> None:
        with self.steps.get_lock():
            self.steps.value += n


class _Tally:
    """The parent's progress bar, advanced by its own steps and by those the children counted since."""

    def __init__(self, bar: tqdm, steps: Synchronized) -> None:
        self.bar, self.steps = bar, steps

    def update(self, n: int) -> None:
        with self.steps.get_lock():
            n, self.steps.value = n + self.steps.value, 0
        self.bar.update(n)


class _Settling:
    """One refinement's settings, and :meth:`run`, which refines a share of its batches."""

    def __init__(
        self,
        avatar: Avatar,
        data: TrainingData,
        geometry: SubjectGeometry,
        weights: LossWeights,
        lr: float,
        steps: int,
        seed: int,
        hold_appearance: bool,
        coarse_steps: int,
        dynamic_only: bool,
        advance: Callable[[int], None],
    ) -> None:
        self.avatar, self.data, self.geometry, self.weights, self.lr = avatar, data, geometry, weights, lr
        self.steps, self.seed, self.hold_appearance, self.coarse_steps = steps, seed, hold_appearance, coarse_steps
        self.dynamic_only, self.advance = dynamic_only, advance
        """Called with the steps taken: a progress bar's update."""

    def run(self, corrections: PoseCorrections, batches: list[list[int]], share: range) -> list[int]:
        """Refine ``corrections``' rows of the batches ``share`` (positions in ``batches``, lists of
        image indices), each batch for all its steps; returns the frame keys refined."""
        objective = HeldAppearance(
            self.avatar.model, self.avatar.identity_map(), corrections, self.weights, None, self.dynamic_only
        )
        optimizer = LazyAdam([{"params": list(corrections.parameters()), "lr": self.lr, "lazy": True}])
        frames = []
        for position in share:
            with profile.part(profile.DATA):
                samples = self.data.load_group(0, batches[position])
            frames += [sample.frame_key for sample in samples]
            self._batch(objective, optimizer, samples, position)
        return frames

    def _batch(self, objective: HeldAppearance, optimizer: LazyAdam, samples: list[Sample], position: int) -> None:
        """All the steps of one batch of ``samples``, the ``position``-th batch of the refinement."""
        steps, coarse_steps = self.steps, self.coarse_steps
        if not samples:
            self.advance(steps)
            return
        with profile.part(profile.DATA):
            coarse = coarse_samples(samples) if coarse_steps else samples
        objective.release()
        parameters = list(objective.corrections.parameters())
        for step in range(steps):
            objective.holding = self.hold_appearance or step < coarse_steps
            shown = coarse if step < coarse_steps else samples
            height, width = shown[0].camera.height, shown[0].camera.width
            optimizer.zero_grad(set_to_none=False)
            with profile.part(profile.DATA):
                backgrounds = draw_backgrounds(
                    TRAINING_BACKGROUND, len(samples), height, width, (self.seed, REFINE_SEED_SALT, step, position)
                )
            loss, _ = objective(shown, self.geometry, backgrounds)
            with profile.part(profile.LOSSES_BACKWARD):
                loss.backward()
            self.advance(1)
            with profile.part(profile.GUARD):
                finite = all_finite(p.grad for p in parameters)
            if not finite:
                log.warning(
                    "pose refinement, images %s, step %d: non-finite gradient; step skipped",
                    [s.image_index for s in samples],
                    step,
                )
                continue
            with profile.part(profile.OPTIMISER):
                optimizer.step()
