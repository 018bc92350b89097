"""Training data: subjects as identities, deterministic batches, per-frame pose corrections.

A step's global batch is drawn from (seed, step) alone, so a resumed run sees exactly the
batches an uninterrupted one would, and a run split over W processes sees the same global
batch as one process. The global batch is ``shards`` groups of ``images_per_shard`` images;
each group comes from one identity (one identity-map evaluation serves the whole group).
A process computes the groups assigned to it and averages over them; DDP's gradient mean
over processes then equals the single-process mean over all groups.
"""

from __future__ import annotations

import copy
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from torch import Tensor, nn

from pghm.body.model import BodyModel
from pghm.errors import DatasetError, PghmError, listed
from pghm.io.read_errors import IMAGE_READ_ERRORS
from pghm.splat import Camera
from pghm.subject import Frame, Subject, open_subjects, read_mask, stated_pose_noise
from pghm.subject.format import size_problem
from pghm.train.person_crop import Crop, crop_size, mask_box, place
from pghm.train.pose_smoothing import smooth_track

log = logging.getLogger(__name__)
SHOWN_FILES = 5
"""Unopenable files an error names before "and N more"."""

STEP_SEED_STRIDE = 1_000_003
"""Mixes the step into the sampling seed: generator seed = seed * stride + step."""
SAMPLE_CACHE_BYTES = 1 << 30
"""Most bytes of decoded samples a :class:`TrainingData` keeps in memory: a fit draws each image
hundreds of times, and reading one (two PNGs decoded, cropped, converted) costs about 5 ms, a
twentieth of a stage step. A 100-frame capture's crops take about 140 MB; past the limit a sample is
read from its files at each use."""


@dataclass(frozen=True)
class Sample:
    """One training image of one identity.

    Attributes:
        identity: index of the identity (subject) in the data set.
        image_index: index of the image within its subject.
        frame_key: global index of the pose (the frame, shared by the views of one instant).
        image: (3, H, W) float32 target, white background.
        mask: (1, H, W) float32, 1 on the subject, 0 elsewhere.
        camera: the image's camera.
        rotations: (J, 3) pose to train on: the stored estimate (possibly noisy), smoothed
            over time, or exact (see :class:`TrainingData`).
        translation: (3,) root translation, likewise.
        crop: the box of the frame that image, mask and camera hold (:mod:`pghm.train.person_crop`),
            or None for the whole frame.
    """

    identity: int
    image_index: int
    frame_key: int
    image: Tensor
    mask: Tensor
    camera: Camera
    rotations: Tensor
    translation: Tensor
    crop: Crop | None = None


def _smoothed_poses(subject: Subject, images: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """(n, J, 3) rotations and (n, 3) translations of all the subject's images, the ``images``
    rows replaced by their frames' estimates smoothed over time (the views of a frame share one)."""
    arrays = subject.arrays
    frame_of = arrays.frame_index[images] if arrays.frame_index is not None else images
    frames, first = np.unique(frame_of, return_index=True)
    rotations, translation = smooth_track(
        frames,
        torch.from_numpy(arrays.rotations[images[first]]),
        torch.from_numpy(arrays.translation[images[first]]),
        sigma,
    )
    out_rotations, out_translation = arrays.rotations.copy(), arrays.translation.copy()
    row = np.searchsorted(frames, frame_of)
    out_rotations[images], out_translation[images] = rotations.numpy()[row], translation.numpy()[row]
    return out_rotations, out_translation


ESTIMATOR_ROTATION_SIGMA = math.radians(2.0)
"""Per-axis standard deviation (radians) of a pose estimator's joint rotations when a subject does
not state its own (meta.json ``pose_noise``): the synthetic data's (``SynthConfig.pose_noise_deg``)."""
ESTIMATOR_TRANSLATION_SIGMA = 0.01
"""Per-axis standard deviation (metres) of its root translation (``SynthConfig.translation_noise_m``)."""


def pose_noise(subject: Subject) -> tuple[float, float]:
    """(rotation sigma in radians, translation sigma in metres) of the subject's stored poses:
    what its meta.json states (:func:`stated_pose_noise`), else the synthetic data's defaults.

    The scale of the Gaussian prior on the subject's pose corrections: a capture's estimates
    are several times noisier than the synthetic data's, and a prior at the synthetic scale
    holds their corrections back (docs/capture.md).
    """
    try:
        stated = stated_pose_noise(subject.meta)
    except ValueError as error:
        raise DatasetError(f"{subject.directory / 'meta.json'}: {error}") from None
    rotation, translation = stated if stated is not None else (0.0, 0.0)
    # Not stated, or exact poses (0): the default width (a prior of zero width has no finite value).
    return (
        math.radians(rotation) if rotation > 0 else ESTIMATOR_ROTATION_SIGMA,
        translation if translation > 0 else ESTIMATOR_TRANSLATION_SIGMA,
    )


class KeptSamples(dict):
    """Samples by (identity, image index), kept while they fit in :data:`SAMPLE_CACHE_BYTES`."""

    def __init__(self) -> None:
        super().__init__()
        self.bytes = 0

    def keep(self, key: tuple[int, int], sample: Sample) -> Sample:
        """``sample``, kept under ``key`` if it fits."""
        size = sample.image.nbytes + sample.mask.nbytes
        if self.bytes + size <= SAMPLE_CACHE_BYTES:
            self[key] = sample
            self.bytes += size
        return sample


class TrainingData:
    """The identities (subject folders) of a data set and their training images.

    Args:
        root: a subject folder, or a data set folder of subject folders (one identity each).
        split: which images to train on ("train").
        max_identities: use only the first this-many subjects (None: all).
        true_poses: use the exact poses synthetic subjects carry (``rotations_true``)
            instead of the estimates, to measure appearance apart from pose error.
        pose_smoothing: standard deviation in frames of a Gaussian filter applied over time
            to the split's estimated poses (see :mod:`pghm.train.pose_smoothing`); 0: as stored.
        crop_margin: cut each image to the person's box with this margin in pixels
            (:mod:`pghm.train.person_crop`); None: whole frames (what evaluation measures).
    """

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        max_identities: int | None = None,
        true_poses: bool = False,
        pose_smoothing: float = 0.0,
        crop_margin: int | None = None,
    ) -> None:
        root = Path(root)
        if not root.is_dir():
            raise DatasetError(f"{root}: data folder not found")
        self.subjects = open_subjects(root)
        if max_identities is not None:
            if max_identities < 1:
                raise DatasetError(f"max_identities must be at least 1, got {max_identities}")
            if max_identities > len(self.subjects):
                raise DatasetError(
                    f"{root}: asked for {max_identities} identities, the data set holds {len(self.subjects)}"
                )
            self.subjects = self.subjects[:max_identities]
        if not self.subjects:
            raise DatasetError(f"{root}: the data set lists no subjects")
        body_names = {subject.arrays.body for subject in self.subjects}
        if len(body_names) != 1:
            raise DatasetError(f"{root}: subjects use different body models {sorted(body_names)}")
        self.body_name = body_names.pop()
        self.true_poses = true_poses
        if true_poses and any(subject.arrays.rotations_true is None for subject in self.subjects):
            raise DatasetError(f"{root}: no exact poses (rotations_true) to evaluate with; this is not synthetic data")
        self.images = [np.asarray(subject.split(split).indices, dtype=np.int64) for subject in self.subjects]
        self.split = split
        self.bad: set[tuple[int, int]] = set()
        self._kept = KeptSamples()
        for subject, images in zip(self.subjects, self.images):
            if len(images) == 0:
                raise DatasetError(f"{subject.directory}: no '{split}' images")
            if (problem := size_problem(subject.arrays.width, subject.arrays.height)) is not None:
                raise DatasetError(f"{subject.directory / 'cameras.npz'}: {problem}")
            self._check_files(subject, images)
        # One pose-correction slot per (identity, frame): the views of an instant share it.
        self.frame_offsets = []
        offset = 0
        for subject in self.subjects:
            self.frame_offsets.append(offset)
            frames = subject.arrays.frame_index
            offset += int(frames.max()) + 1 if frames is not None else len(subject)
        self.num_frames = offset
        self.pose_noise = [pose_noise(subject) for subject in self.subjects]
        self.smoothed_poses = [
            _smoothed_poses(subject, images, pose_smoothing) if pose_smoothing else None
            for subject, images in zip(self.subjects, self.images)
        ]
        self.crops: list[dict[int, Crop]] = [
            self._person_crops(identity, crop_margin) if crop_margin is not None else {}
            for identity in range(len(self.subjects))
        ]

    def _person_crops(self, identity: int, margin: int) -> dict[int, Crop]:
        """The crop of each readable training image of an identity: one size, around each mask."""
        subject = self.subjects[identity]
        boxes = {}
        for index in self.images[identity].tolist():
            if (identity, index) in self.bad:
                continue
            try:
                boxes[index] = mask_box(read_mask(subject.mask_path(index)))
            except DatasetError as error:
                self._skip(identity, index, error)
        self._check_some_readable(identity)
        width, height = int(subject.arrays.width.max()), int(subject.arrays.height.max())
        size = crop_size([box for box in boxes.values() if box is not None], width, height, margin)
        return {index: place(box, size, width, height) for index, box in boxes.items()}

    def _check_files(self, subject: Subject, images: np.ndarray) -> None:
        """Every image and mask of the split opens, with the size cameras.npz gives (PNG headers only).

        A missing file or a wrong size is a broken data set, and a file that cannot be opened (a
        broken link, a link loop, no permission, not an image) is damage found before any step:
        DatasetError, every such file named in one line, as ``pghm capture`` refuses a frame
        folder. Pixels damaged behind a valid header are found only when decoded: that frame is
        left out with a warning (see :meth:`load_group`).
        """
        arrays = subject.arrays
        unreadable: list[str] = []
        for index in images.tolist():
            size = (int(arrays.width[index]), int(arrays.height[index]))
            for path in (subject.image_path(index), subject.mask_path(index)):
                if not os.path.lexists(path):
                    raise DatasetError(
                        f"{path}: missing ({self.split} image {index}); run pghm data check {subject.directory}"
                    )
                try:
                    with Image.open(path) as image:
                        found = image.size
                except IMAGE_READ_ERRORS:
                    unreadable.append(str(path.relative_to(subject.directory)))
                    continue
                if found != size:
                    raise DatasetError(
                        f"{path}: {found[0]}x{found[1]} pixels, cameras.npz says {size[0]}x{size[1]}; "
                        f"run pghm data check {subject.directory}"
                    )
        if unreadable:
            raise DatasetError(
                f"{subject.directory}: {len(unreadable)} file(s) of its '{self.split}' images and masks cannot be "
                f"opened ({listed(unreadable, SHOWN_FILES)}): a broken link, no permission or not a PNG; "
                f"run pghm data check {subject.directory}"
            )

    def _skip(self, identity: int, index: int, error: object) -> None:
        self.bad.add((identity, index))
        log.warning("skipping image %d of %s: %s", index, self.subjects[identity].directory, error)

    def _check_some_readable(self, identity: int) -> None:
        """DatasetError once every image of an identity has been skipped: training would silently do nothing."""
        images = self.images[identity]
        if all((identity, int(index)) in self.bad for index in images):
            raise DatasetError(
                f"{self.subjects[identity].directory}: none of its {len(images)} '{self.split}' images can be read"
            )

    @property
    def num_identities(self) -> int:
        return len(self.subjects)

    def check_body(self, body_name: str, owner: str | Path) -> None:
        """:class:`DatasetError` naming the subject's poses.npz when its body is not ``body_name``, the
        body of ``owner`` (the avatar or prior file the data meets): one body's poses mean nothing to another."""
        if self.body_name != body_name:
            raise DatasetError(
                f"{self.subjects[0].directory / 'poses.npz'}: poses of the '{self.body_name}' body, "
                f"and {owner} is of the '{body_name}' body"
            )

    def shape(self, identity: int) -> Tensor:
        return torch.as_tensor(self.subjects[identity].arrays.shape, dtype=torch.float32)

    def pose_sigmas(self) -> tuple[Tensor, Tensor]:
        """(num_frames,) rotation sigmas (radians) and (num_frames,) translation sigmas (metres) of
        every frame's stored pose: its subject's :func:`pose_noise`."""
        rotation, translation = torch.empty(self.num_frames), torch.empty(self.num_frames)
        ends = [*self.frame_offsets[1:], self.num_frames]
        for start, end, (r, t) in zip(self.frame_offsets, ends, self.pose_noise):
            rotation[start:end], translation[start:end] = r, t
        return rotation, translation

    def restricted(self, images: list[int]) -> TrainingData:
        """This data set of one subject training on ``images`` (its image indices) only: the same
        poses, crops and pose-correction rows, fewer images."""
        if len(self.subjects) != 1:
            raise PghmError(f"restricting training images needs one subject, found {len(self.subjects)}")
        kept = copy.copy(self)
        kept.images = [np.asarray(images, dtype=np.int64)]
        return kept

    def pose_corrections(self, body: BodyModel) -> PoseCorrections:
        """Zero corrections of the estimated joints of every frame, their prior as wide as each
        frame's stated noise (:meth:`pose_sigmas`)."""
        return PoseCorrections.of_estimated_joints(self.num_frames, body, self.pose_sigmas())

    def load(self, identity: int, image_index: int) -> Sample:
        """One image and its annotations: read from its files at the first use, and then the same
        sample from memory while the samples kept fit in :data:`SAMPLE_CACHE_BYTES`."""
        key = (identity, image_index)
        if (sample := self._kept.get(key)) is None:
            sample = self._kept.keep(key, self._read(identity, image_index))
        return sample

    def _read(self, identity: int, image_index: int) -> Sample:
        """Read one image and its annotations from the subject's files."""
        subject = self.subjects[identity]
        frame = subject[image_index]
        camera = Camera.from_matrices(
            torch.as_tensor(frame.K, dtype=torch.float32),
            torch.as_tensor(frame.world_to_camera, dtype=torch.float32),
            width=int(frame.image.shape[1]),
            height=int(frame.image.shape[0]),
        )
        image, mask = frame.image, frame.mask
        crop = self.crops[identity].get(image_index)
        if crop is not None:
            image, mask, camera = crop.image(image), crop.image(mask), crop.camera(camera)
        return Sample(
            identity=identity,
            image_index=image_index,
            frame_key=self.frame_offsets[identity] + int(frame.frame_index),
            image=torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float(),
            mask=torch.from_numpy(np.ascontiguousarray(mask))[None].float(),
            camera=camera,
            crop=crop,
            **self._pose(identity, image_index, frame),
        )

    def _pose(self, identity: int, image_index: int, frame: Frame) -> dict[str, Tensor]:
        """The pose an image is trained on: exact, smoothed or as stored."""
        if self.true_poses:
            rotations, translation = frame.rotations_true, frame.translation_true
        elif (smoothed := self.smoothed_poses[identity]) is not None:
            rotations, translation = smoothed[0][image_index], smoothed[1][image_index]
        else:
            rotations, translation = frame.rotations, frame.translation
        return {
            "rotations": torch.as_tensor(rotations, dtype=torch.float32),
            "translation": torch.as_tensor(translation, dtype=torch.float32),
        }

    def plan(
        self, seed: int, step: int, shards: int, images_per_shard: int, same_instant: bool = True
    ) -> list[tuple[int, list[int]]]:
        """The global batch of ``step``: ``shards`` (identity, image indices) groups.

        With ``same_instant``, a group of a multi-view subject is views of one time step
        (they share the skinning and the pose branch); otherwise images are drawn freely.
        """
        gen = np.random.default_rng(seed * STEP_SEED_STRIDE + step)
        groups = []
        for _ in range(shards):
            identity = int(gen.integers(self.num_identities))
            pool = self.images[identity]
            frames = self.subjects[identity].arrays.frame_index
            if same_instant and frames is not None and len(np.unique(frames[pool])) < len(pool):
                instant = gen.choice(np.unique(frames[pool]))
                pool = pool[frames[pool] == instant]
            replace = len(pool) < images_per_shard
            chosen = gen.choice(pool, size=images_per_shard, replace=replace)
            groups.append((identity, [int(i) for i in chosen]))
        return groups

    def load_group(self, identity: int, image_indices: list[int]) -> list[Sample]:
        """The readable samples of a group; a corrupted image is reported once and skipped."""
        samples = []
        for index in image_indices:
            if (identity, index) in self.bad:
                continue
            try:
                samples.append(self.load(identity, index))
            except (DatasetError, PghmError, *IMAGE_READ_ERRORS) as error:
                self._skip(identity, index, error)
                self._check_some_readable(identity)
        return samples


class PoseCorrections(nn.Module):
    """Learned per-frame corrections of the stored poses (the paper refines noisy poses).

    corrected rotations[:, bones] = stored + delta_rotations[frame] (axis-angle, small deltas),
    corrected translation = stored + delta_translation[frame]; both start at zero.

    Only the estimator's joints (``bones``) are corrected: the other bones (fingers, face,
    twist bones) are not estimated, so a pose estimator's error is not in them, and their
    photometric gradients are too weak to steer Adam's unit-sized first steps.

    Args:
        num_frames: number of frames (rows).
        bones: (K,) indices of the corrected bones.
        sigmas: (num_frames,) rotation sigmas (radians) and (num_frames,) translation sigmas
            (metres) of the stored poses' noise, or one of each for every frame: the scale of
            :meth:`prior` (:meth:`TrainingData.pose_sigmas`); None: the synthetic data's.
    """

    def __init__(self, num_frames: int, bones: list[int], sigmas: tuple[Tensor, Tensor] | None = None) -> None:
        super().__init__()
        if sigmas is None:
            sigmas = torch.tensor(ESTIMATOR_ROTATION_SIGMA), torch.tensor(ESTIMATOR_TRANSLATION_SIGMA)
        self.register_buffer("bones", torch.tensor(sorted(set(bones)), dtype=torch.long), persistent=False)
        # Not in checkpoints: the data state them again on resume.
        rotation_sigma, translation_sigma = (torch.as_tensor(s).float().expand(num_frames).clone() for s in sigmas)
        self.register_buffer("rotation_sigma", rotation_sigma, persistent=False)
        self.register_buffer("translation_sigma", translation_sigma, persistent=False)
        self.rotations = nn.Parameter(torch.zeros(num_frames, len(self.bones), 3))
        self.translation = nn.Parameter(torch.zeros(num_frames, 3))

    @classmethod
    def of_estimated_joints(
        cls, num_frames: int, body: BodyModel, sigmas: tuple[Tensor, Tensor] | None = None
    ) -> PoseCorrections:
        """Corrections of the body's canonical joints (those a pose estimator reports)."""
        return cls(num_frames, list(body.joint_map.values()), sigmas)

    def prior(self, frame_keys: Tensor) -> Tensor:
        """The corrections of frames (B,) in units of their estimates' noise, averaged over frames:

            mean_b [ sum_j |delta_r[b, j]|^2 / sigma_r[b]^2 + |delta_t[b]|^2 / sigma_t[b]^2 ],

        minus twice the log of a zero-mean Gaussian prior on them, up to a constant. Adam steps
        every coordinate at its learning rate whatever the size of its gradient, so those a
        single view barely sees (the depth of the root, the wrists, ankles and head: gradients
        10 to 100 times weaker) drift with the noise; the prior holds them near the estimate
        while the image moves the well-seen ones.
        """
        rotations = self.rotations[frame_keys].square().flatten(1).sum(1) / self.rotation_sigma[frame_keys].square()
        translation = self.translation[frame_keys].square().sum(1) / self.translation_sigma[frame_keys].square()
        return (rotations + translation).mean()

    def forward(self, frame_keys: Tensor, rotations: Tensor, translation: Tensor) -> tuple[Tensor, Tensor]:
        """Corrected (B, J, 3) rotations and (B, 3) translations for frames (B,)."""
        rotations = rotations.index_add(1, self.bones, self.rotations[frame_keys])
        return rotations, translation + self.translation[frame_keys]
