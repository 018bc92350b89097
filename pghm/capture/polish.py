"""Capture's optional last stage: every frame's pose aligned to its own image through an avatar.

The body fit places the body from landmarks and masks to 1.1-1.6 % of the person's height
(bench_capture's c), while an avatar's held-out frame rendered 0.27 % (under a pixel) off the pose
it learned already loses 1.5 dB (``benchmarks/bench_pose_error.py``): no estimator that reads a frame
without an avatar of the person is that close. The polish makes one: it personalises a prior on
*every* frame of the capture (:func:`pghm.train.fit.fit` on :data:`~pghm.data.subject.ALL_SPLIT`),
settles each frame's pose correction against the finished avatar for :data:`POLISH_TRACK_STEPS`
steps (:func:`pghm.train.test_poses.refine_poses`), and stores

    rotations'[f, bones] = rotations[f, bones] + delta_r[f],    translation'[f] = translation[f] + delta_t[f]

for the estimator's joints (``bones``) of every frame f; shape, cameras, images and masks are
unchanged, and the avatar is discarded. ``pghm fit`` then learns its own avatar from the training
split alone, so no test image reaches the evaluated avatar; a test frame's pose has seen its own
image, as any pose estimator's does, and here once, in the capture, rather than against the
evaluated avatar (the test-time refinement of InstantAvatar and GART, ``pghm eval
--refine-poses``). It costs a fit with settling: about 18 minutes for 100 frames on 2 cores
(docs/capture.md).
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from pghm.data.subject import ALL_SPLIT, Subject, write_subject
from pghm.io.avatar import Avatar, recorded_path
from pghm.model import ModelConfig
from pghm.train.fit import TRACK_STEPS, FitConfig, fit

POLISH_TRACK_STEPS = TRACK_STEPS
"""Steps of each frame's pose refinement against the finished avatar. Always run, unlike ``pghm
fit``'s settling (only for subjects whose frames stage 2 visits fewer than 20 times), since the
corrections are what the polish keeps."""


def polish_poses(
    subject_dir: str | Path,
    prior: str | Path | Avatar | ModelConfig,
    config: FitConfig | None = None,
    progress: bool = True,
) -> dict:
    """Align every frame's stored pose in the subject folder ``subject_dir`` to its image (module
    docstring), rewriting its poses.npz and adding meta.json's ``polish`` record, which is returned.

    ``prior``: the prior to personalise (a file, a loaded prior, or a :class:`ModelConfig` to start
    from scratch, for tests); ``config``: the fit's settings (default: ``pghm fit``'s), whose split
    and pose settings (corrections of the stored poses, settled) the polish sets; ``progress``: the
    fit's bars on stderr.
    """
    subject_dir = Path(subject_dir)
    config = replace(
        config or FitConfig(), split=ALL_SPLIT, track_steps=POLISH_TRACK_STEPS, refine_poses=True, pose_smoothing=0.0
    )
    if not progress:
        config = replace(
            config, stage1=replace(config.stage1, progress=False), stage2=replace(config.stage2, progress=False)
        )
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=".polish-", dir=subject_dir) as scratch:
        avatar = fit(subject_dir, prior, Path(scratch) / "polish.pt", config)
    subject = Subject.open(subject_dir)
    arrays = subject.arrays
    track = avatar.pose_track
    frames = arrays.frame_index if arrays.frame_index is not None else np.arange(len(arrays))
    delta_r, delta_t, _, _ = track.at(frames, max_gap=0)  # every frame was trained on: its own row
    delta_r, delta_t = delta_r.numpy(), delta_t.numpy()  # (F, K, 3) axis-angle, (F, 3) metres
    rotations = np.array(arrays.rotations, dtype=np.float32)
    rotations[:, track.bones.numpy()] += delta_r
    translation = np.asarray(arrays.translation, dtype=np.float32) + delta_t
    angles = np.linalg.norm(delta_r, axis=-1)
    moved = np.linalg.norm(delta_t, axis=-1)
    record = {
        "prior": recorded_path(prior) if isinstance(prior, (str, Path)) else "(in memory)",
        "frames": len(frames),
        "steps": avatar.metadata["steps"],
        "track_steps": POLISH_TRACK_STEPS,
        "seconds": round(time.perf_counter() - started, 1),
        "mean_rotation_change_deg": round(math.degrees(float(angles.mean())), 3),
        "mean_translation_change_mm": round(1000 * float(moved.mean()), 2),
    }
    polished = replace(arrays, rotations=rotations, translation=translation)
    write_subject(subject_dir, polished, {**subject.meta, "polish": record})
    return record
