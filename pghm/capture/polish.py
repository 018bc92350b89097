"""Capture's optional last stage: the held-out frames' poses aligned to their images through an avatar.

The body fit places the body from landmarks and masks to 1.1-1.6 % of the person's height
(bench_capture's c), while an avatar's held-out frame rendered 0.27 % (under a pixel) off the pose
it learned already loses 1.5 dB (``benchmarks/bench_pose_error.py``): no estimator that reads a frame
without an avatar of the person is that close. The polish makes one: it personalises a prior on
*every* frame of the capture (:func:`pghm.train.fit.fit` on :data:`~pghm.subject.ALL_SPLIT`,
stage 2 correcting each frame's pose), settles the correction of each frame outside the training
split against the finished avatar for :data:`POLISH_TRACK_STEPS` steps
(:func:`pghm.train.pose_refine.refine_poses`), and stores, for those held-out frames f,

    rotations'[f, bones] = rotations[f, bones] + delta_r[f],    translation'[f] = translation[f] + delta_t[f]

for the estimator's joints (``bones``), listing them in meta.json's ``aligned_frames``; the training
frames' poses, shape, cameras, images and masks are unchanged, and the avatar is discarded. The
training frames are left to ``pghm fit``, which corrects and settles their poses itself against the
avatar it learns from them alone, and no test image reaches that avatar. Settling every frame here
too took 2.5 times as long and scored the held-out frames no better (docs/lab/capture-history.md).
A test frame's pose has seen its own image, as any pose estimator's does, here once, in the capture,
rather than against the evaluated avatar (the test-time refinement of InstantAvatar and GART, ``pghm
eval --refine-poses``). It costs a fit and the held-out frames' settling: about 7 minutes for 100
frames on 2 cores (docs/capture.md).
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from pghm.body import load_body
from pghm.io.avatar import Avatar, recorded_path
from pghm.model import ModelConfig
from pghm.subject import ALL_SPLIT, Subject, write_subject
from pghm.train.data import TrainingData
from pghm.train.fit import POSE_LR, TRACK_STEPS, FitConfig, fit
from pghm.train.pose_refine import refine_poses
from pghm.train.pose_track import track_corrections

POLISH_TRACK_STEPS = TRACK_STEPS
"""Steps of each held-out frame's pose refinement against the finished avatar, as ``pghm fit``
settles its training frames."""


def held_out_images(subject: Subject) -> list[int]:
    """Image indices outside the subject's "train" split: the frames ``pghm fit`` does not correct."""
    train = set(subject.split("train").indices)
    return [i for i in range(len(subject)) if i not in train]


def polish_poses(
    subject_dir: str | Path,
    prior: str | Path | Avatar | ModelConfig,
    config: FitConfig | None = None,
    progress: bool = True,
) -> dict:
    """Align the held-out frames' stored poses in the subject folder ``subject_dir`` to their
    images (module docstring), rewriting its poses.npz and adding meta.json's ``polish`` record,
    which is returned, and the frames to its ``aligned_frames`` (a fit's pose track leaves them as
    stored, :meth:`pghm.io.avatar.PoseTrack.at`).

    ``prior``: the prior to personalise (a file, a loaded prior, or a :class:`ModelConfig` to start
    from scratch, for tests); ``config``: the fit's settings (default: ``pghm fit``'s), whose split
    and pose settings (corrections of the stored poses, no settling of the training frames) the
    polish sets, with no detail stage; ``progress``: the fit's and the settling's bars on stderr.
    """
    subject_dir = Path(subject_dir)
    config = replace(config or FitConfig(), split=ALL_SPLIT, track_steps=0, refine_poses=True, pose_smoothing=0.0)
    config.detail = replace(config.detail, steps=0)  # the avatar aligns poses and is discarded
    if not progress:
        config = replace(
            config, stage1=replace(config.stage1, progress=False), stage2=replace(config.stage2, progress=False)
        )
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=".polish-", dir=subject_dir) as scratch:
        avatar = fit(subject_dir, prior, Path(scratch) / "polish.pt", config)
    subject = Subject.open(subject_dir)
    held_out = held_out_images(subject)
    data = TrainingData(subject_dir, split=ALL_SPLIT)
    # Every frame was trained on: each starts from its own stage-2 correction.
    corrections, _ = track_corrections(avatar.pose_track, data, load_body(data.body_name, config.body_model_path))
    refine_poses(
        avatar,
        data,
        POLISH_TRACK_STEPS,
        config.stage2.loss,
        POSE_LR,
        corrections,
        images=held_out,
        body_model_path=config.body_model_path,
        progress=progress,
        desc="polish: settle held-out poses",
    )
    arrays = subject.arrays
    frames = arrays.frame_index if arrays.frame_index is not None else np.arange(len(arrays))
    rows = frames[held_out] + data.frame_offsets[0]
    delta_r = corrections.rotations.detach()[rows].numpy()  # (H, K, 3) axis-angle
    delta_t = corrections.translation.detach()[rows].numpy()  # (H, 3) metres
    rotations = np.array(arrays.rotations, dtype=np.float32)
    translation = np.array(arrays.translation, dtype=np.float32)
    bones = corrections.bones.numpy()
    rotations[np.ix_(held_out, bones)] += delta_r
    translation[held_out] += delta_t
    record = {
        "prior": recorded_path(prior) if isinstance(prior, (str, Path)) else "(in memory)",
        "frames": len(set(frames[held_out].tolist())),
        "fit_images": int(avatar.metadata["training_images"]),
        "steps": avatar.metadata["steps"],
        "track_steps": POLISH_TRACK_STEPS,
        "seconds": round(time.perf_counter() - started, 1),
        "mean_rotation_change_deg": round(math.degrees(float(np.linalg.norm(delta_r, axis=-1).mean())), 3),
        "mean_translation_change_mm": round(1000 * float(np.linalg.norm(delta_t, axis=-1).mean()), 2),
    }
    polished = replace(arrays, rotations=rotations, translation=translation)
    aligned = sorted(subject.aligned_frames() | {int(f) for f in frames[held_out]})
    write_subject(subject_dir, polished, {**subject.meta, "polish": record, "aligned_frames": aligned})
    return record
