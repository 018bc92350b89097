"""The poses a fit learned for its video, carried to the frames it held out.

Stage 2 of ``pghm fit`` corrects the stored pose of every training frame
(:class:`~pghm.train.data.PoseCorrections`); the avatar keeps the corrections as its pose track
(:class:`~pghm.io.avatar.PoseTrack`). A held-out frame f between two trained frames a < f < b
takes their corrections interpolated in time,

    delta_f = (1 - w) delta_a + w delta_b,    w = (f - a) / (b - a),

on top of its own stored pose (:meth:`~pghm.io.avatar.PoseTrack.at`; the avatar replaying its
video, :func:`~pghm.motion.open_motion.subject_motion`, does the same). That carries what
neighbouring frames' errors share, not an estimate's own error, so a capture's fit then aligns
each held-out frame to its own image from there (:func:`pghm.train.fit.align_held_out`), and the
track keeps those corrections too, listed as ``aligned``: those frames' poses have seen their
images, as with ``pghm eval --refine-poses``. A frame that was itself trained on (another camera's
view of a training instant) takes its own correction exactly. A frame not bracketed by trained
frames at most :data:`~pghm.io.avatar.MAX_BRACKET_STEPS` frame steps apart (a novel pose after the
video, or a long stretch of dropped frames) keeps its stored pose.
"""

from __future__ import annotations

import numpy as np
import torch

from pghm.body.model import BodyModel
from pghm.errors import PghmError
from pghm.io.avatar import MAX_BRACKET_STEPS, PoseTrack
from pghm.train.data import PoseCorrections, TrainingData


def frame_numbers(data: TrainingData, images) -> np.ndarray:
    """(N,) the frame number of each of ``images`` (N image indices of the data's single subject):
    its ``frame_index``, or the image index itself when the subject records none."""
    frames = data.subjects[0].arrays.frame_index
    images = np.asarray(images, dtype=np.int64)
    return frames[images] if frames is not None else images


def _frames_of(data: TrainingData) -> np.ndarray:
    """(F,) distinct frame numbers of the data's (single subject's) images, ascending."""
    return np.unique(frame_numbers(data, data.images[0]))


def learned_track(corrections: PoseCorrections, data: TrainingData) -> PoseTrack:
    """The pose track of a fit: ``corrections``' rows of the frames ``data`` (one subject) trains on."""
    frames = _frames_of(data)
    rows = torch.as_tensor(frames + data.frame_offsets[0])
    return PoseTrack(
        frames=torch.as_tensor(frames, dtype=torch.int64),
        bones=corrections.bones.clone(),
        rotations=corrections.rotations.detach()[rows].clone(),
        translation=corrections.translation.detach()[rows].clone(),
        poses=data.subjects[0].arrays.poses_digest(),
    )


def track_corrections(track: PoseTrack, data: TrainingData, body: BodyModel) -> tuple[PoseCorrections, dict]:
    """Corrections of every frame of ``data`` (one subject, e.g. its test split) from ``track``.

    Returns the corrections and how many of the data's frames took a trained frame's own
    correction ("trained"), their own correction aligned to their image after the fit
    ("aligned", :attr:`PoseTrack.aligned`), an interpolated one ("interpolated") or none
    ("stored": not bracketed by trained frames, or aligned to its own image by the capture,
    meta.json's ``aligned_frames``).
    """
    subject = data.subjects[0]
    if track.poses != subject.arrays.poses_digest():
        raise PghmError(
            f"{subject.directory}: the avatar's pose track was learned on other poses "
            "(another subject, or its poses.npz changed since the fit)"
        )
    corrections = data.pose_corrections(body)
    if not torch.equal(track.bones, corrections.bones):
        raise PghmError(f"the avatar's pose track corrects other bones than {data.body_name}'s estimated joints")
    frames = _frames_of(data)
    aligned = subject.aligned_frames()
    rotations, translation, found, exact = track.at(frames, MAX_BRACKET_STEPS * subject.arrays.frame_step(), aligned)
    rows = torch.as_tensor(frames[found] + data.frame_offsets[0])
    with torch.no_grad():
        corrections.rotations[rows], corrections.translation[rows] = rotations[found], translation[found]
    seen = exact & np.isin(frames, track.aligned.numpy())
    counts = {
        "trained": int((exact & ~seen).sum()),
        "aligned": int(seen.sum()),
        "interpolated": int((found & ~exact).sum()),
        "stored": int((~found).sum()),
    }
    return corrections.requires_grad_(False), counts
