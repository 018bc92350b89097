"""The poses a fit learned for its video, carried to the frames it held out.

Stage 2 of ``pghm fit`` corrects the stored pose of every training frame
(:class:`~pghm.train.data.PoseCorrections`); the avatar keeps those corrections as its pose
track (:class:`~pghm.io.avatar.PoseTrack`). A capture's pose error changes little from one
frame to the next (its body fit is smoothed over time), so a held-out frame f between two
trained frames a < f < b takes their corrections interpolated in time,

    delta_f = (1 - w) delta_a + w delta_b,    w = (f - a) / (b - a),

on top of its own stored pose. The deltas are small axis-angle vectors, so interpolating them
interpolates the corrections' rotations to first order. A frame that was itself trained on
(another camera's view of a training instant) takes its own correction exactly. A frame not
bracketed by trained frames at most :data:`MAX_BRACKET_STEPS` frame steps apart (a novel pose
after the video, or a long stretch of dropped frames) keeps its stored pose. Only the
training images were used: nothing here looks at the held-out images (unlike
:mod:`pghm.train.test_poses`).
"""

from __future__ import annotations

import numpy as np
import torch

from pghm.body.model import BodyModel
from pghm.data.subject import Subject
from pghm.errors import PghmError
from pghm.io.avatar import PoseTrack
from pghm.train.data import PoseCorrections, TrainingData

MAX_BRACKET_STEPS = 3
"""A held-out frame is interpolated only between trained frames at most this many frame steps
apart (the subject's smallest step between frame numbers): a test frame with a dropped frame
beside it still is; anything farther keeps its stored pose."""


def _frames_of(data: TrainingData) -> np.ndarray:
    """(F,) distinct frame numbers of the data's (single subject's) images, ascending."""
    subject = data.subjects[0]
    images = data.images[0]
    frames = subject.arrays.frame_index
    return np.unique(frames[images] if frames is not None else images)


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


def frame_step(subject: Subject) -> int:
    """The smallest difference between two of the subject's frame numbers (1 for a whole video)."""
    frames = subject.arrays.frame_index
    steps = np.diff(np.unique(frames)) if frames is not None else np.ones(1)
    return int(steps.min()) if len(steps) else 1


def bracket(known: np.ndarray, query: np.ndarray, max_gap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interpolation of values known at frames ``known`` (K,) ascending onto frames ``query`` (Q,).

    Returns (lower, upper, weight), each (Q,): value(q) = (1 - w) value[lower] + w value[upper]
    with rows into ``known``; lower = upper and w = 0 where q is known; lower = upper = -1 where q
    is neither known nor bracketed by known frames at most ``max_gap`` apart.
    """
    if len(known) == 0:
        none = np.full(len(query), -1)
        return none, none.copy(), np.zeros(len(query))
    upper = np.searchsorted(known, query)
    exact = (upper < len(known)) & (known[np.minimum(upper, len(known) - 1)] == query)
    lower = upper - 1
    inside = (lower >= 0) & (upper < len(known))
    a = known[np.clip(lower, 0, len(known) - 1)]
    b = known[np.clip(upper, 0, len(known) - 1)]
    between = inside & ~exact & (b - a <= max_gap)
    weight = np.where(between, (query - a) / np.maximum(b - a, 1), 0.0)
    lower = np.where(exact, upper, np.where(between, lower, -1))
    upper = np.where(exact | between, upper, -1)
    return lower, upper, weight


def track_corrections(track: PoseTrack, data: TrainingData, body: BodyModel) -> tuple[PoseCorrections, dict]:
    """Corrections of every frame of ``data`` (one subject, e.g. its test split) from ``track``.

    Returns the corrections and how many of the data's frames took a trained frame's own
    correction ("trained"), an interpolated one ("interpolated") or none ("stored").
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
    lower, upper, weight = bracket(track.frames.numpy(), frames, MAX_BRACKET_STEPS * frame_step(subject))
    found = lower >= 0
    w = torch.as_tensor(weight[found], dtype=torch.float32)
    lo, hi = torch.as_tensor(lower[found]), torch.as_tensor(upper[found])
    rows = torch.as_tensor(frames[found] + data.frame_offsets[0])
    with torch.no_grad():
        for delta, known in ((corrections.rotations, track.rotations), (corrections.translation, track.translation)):
            weights = w.view(-1, *[1] * (known.dim() - 1))
            delta[rows] = (1 - weights) * known[lo] + weights * known[hi]
    exact = found & (lower == upper)
    counts = {"trained": int(exact.sum()), "interpolated": int((found & ~exact).sum()), "stored": int((~found).sum())}
    return corrections.requires_grad_(False), counts
