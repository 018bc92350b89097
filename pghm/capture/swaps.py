"""Left/right swaps of MediaPipe's landmarks, found over time and undone before the body fit.

MediaPipe labels each frame on its own, and two mistakes recur on walking people:

* the whole body mirrored: a person seen from behind (or side-on) labelled as if facing the
  camera. The 2D points keep their places but left and right trade labels, and the metric
  "world" landmarks are the true ones with left and right traded and depth mirrored
  (z -> -z about the hips): the same image explains both bodies;
* one pair of limbs swapped: the legs (or arms) labelled the other way round where they
  cross or one hides the other.

A label swap makes the labelled points jump between frames while the real body moves a
little, so each kind is decided over the whole video by dynamic programming (Viterbi) with
two states per frame, as observed (0) or swapped (1):

    min over s_1..s_F of  sum_f lambda s_f  +  sum_f c(f - 1, s_f-1; f, s_f) / g_f

where lambda (:data:`SWAP_COST`) is the price of overruling MediaPipe in one frame, g_f the
source-frame gap between kept frames f - 1 and f, and c the jump between the two labellings:
the torso's 2D points (per 10 % of the person's height, :data:`MOTION_SCALE`) plus, for the
whole body, 1 - cos of the turn of its left-right axis (MediaPipe's world landmarks, in the
ground plane), and for a pair of limbs their hip-relative world landmarks (per
:data:`METRIC_SCALE`). A single mislabelled frame costs two jumps if kept and lambda if
swapped; a body really turning moves a few degrees a frame and is kept as observed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pghm.capture.landmarks import LANDMARK_NAMES

SWAP_COST = 0.5
"""lambda: cost of relabelling one frame against MediaPipe, in the jumps' units (a torso
jump of 10 % of the person's height costs 1): a run of mislabelled frames is relabelled when
its two jumps cost more than half a unit per frame of the run."""

MOTION_SCALE = 0.1
"""2D jumps are measured in units of this fraction of the person's height."""

METRIC_SCALE = 0.1
"""Hip-relative 3D jumps are measured in units of this many metres."""


def _pairs(parts: tuple[str, ...]) -> list[tuple[int, int]]:
    return [(LANDMARK_NAMES.index(f"left_{p}"), LANDMARK_NAMES.index(f"right_{p}")) for p in parts]


TORSO_PAIRS = _pairs(("shoulder", "hip"))
LEG_PAIRS = _pairs(("knee", "ankle", "heel", "foot_index"))
ARM_PAIRS = _pairs(("elbow", "wrist", "pinky", "index", "thumb"))
FACE_PAIRS = _pairs(("eye_inner", "eye", "eye_outer", "ear")) + [
    (LANDMARK_NAMES.index("mouth_left"), LANDMARK_NAMES.index("mouth_right"))
]
BODY_PAIRS = FACE_PAIRS + TORSO_PAIRS + ARM_PAIRS + LEG_PAIRS
"""Every left/right pair of MediaPipe's 33 landmarks."""


@dataclass
class Landmarks:
    """One video's landmarks (F frames), as the front end gives them (:class:`Observations` fields).

    Attributes:
        points: (F, 33, 2) pixels.
        confidence: (F, 33).
        world: (F, 33, 3) metres, hip-centred, MediaPipe's axes (z away from the camera).
    """

    points: np.ndarray
    confidence: np.ndarray
    world: np.ndarray


@dataclass
class Repair:
    """What :func:`repair_swaps` changed: (F,) bool per kind, True where the frame was relabelled."""

    body: np.ndarray
    legs: np.ndarray
    arms: np.ndarray


def permutation(pairs: list[tuple[int, int]]) -> np.ndarray:
    """(33,) landmark index -> the index it takes the values of when ``pairs`` trade labels."""
    order = np.arange(len(LANDMARK_NAMES))
    for left, right in pairs:
        order[left], order[right] = right, left
    return order


def traded(marks: Landmarks, pairs: list[tuple[int, int]], mirror_depth: bool) -> Landmarks:
    """``marks`` with ``pairs`` trading labels (new arrays); with ``mirror_depth`` world z -> -z as well
    (the whole body mirrored, module docstring)."""
    order = permutation(pairs)
    world = marks.world[:, order].copy()
    if mirror_depth:
        world[..., 2] *= -1
    return Landmarks(marks.points[:, order], marks.confidence[:, order], world)


def viterbi(unary: np.ndarray, pairwise: np.ndarray) -> np.ndarray:
    """(F,) states minimising sum_f unary[f, s_f] + sum_f pairwise[f - 1, s_f-1, s_f].

    Args:
        unary: (F, S) cost of each state in each frame.
        pairwise: (F - 1, S, S) cost of each transition between consecutive frames.
    """
    total = unary[0].copy()
    back = np.zeros(unary.shape, dtype=np.int64)
    for f in range(1, len(unary)):
        step = total[:, None] + pairwise[f - 1]  # (previous state, state)
        back[f] = step.argmin(0)
        total = step.min(0) + unary[f]
    states = np.zeros(len(unary), dtype=np.int64)
    states[-1] = int(total.argmin())
    for f in range(len(unary) - 1, 0, -1):
        states[f - 1] = back[f, states[f]]
    return states


def _jump_2d(a: np.ndarray, b: np.ndarray, weight: np.ndarray, indices: list[int], height: float) -> np.ndarray:
    """(F - 1,) confidence-weighted mean 2D jump of ``indices`` from ``a``[f - 1] to ``b``[f], per MOTION_SCALE h."""
    distance = np.linalg.norm(b[1:, indices] - a[:-1, indices], axis=-1)
    w = weight[:-1, indices] * weight[1:, indices]
    return (w * distance).sum(1) / np.maximum(w.sum(1), 1e-6) / (MOTION_SCALE * height)


def left_right_axis(world: np.ndarray) -> np.ndarray:
    """(..., 2) unit ground-plane (x, z) direction from the right to the left torso landmarks.

    ``world``: (..., 33, 3) world landmarks.
    """
    left = [pair[0] for pair in TORSO_PAIRS]
    right = [pair[1] for pair in TORSO_PAIRS]
    d = (world[..., left, :] - world[..., right, :]).sum(-2)[..., [0, 2]]
    return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-6)


def _axis_turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(F - 1,) 1 - cos of the angle between the ground-plane left-right axes of world landmarks a[f - 1], b[f]."""
    return 1.0 - (left_right_axis(a)[:-1] * left_right_axis(b)[1:]).sum(-1)


def _decide(
    marks: Landmarks, pairs: list[tuple[int, int]], mirror_depth: bool, height: float, gaps: np.ndarray
) -> tuple[Landmarks, np.ndarray]:
    """Relabel the frames where trading ``pairs`` gives the cheaper path; the new landmarks and (F,) flags."""
    swapped = traded(marks, pairs, mirror_depth)
    states = (marks, swapped)
    indices = [i for pair in (TORSO_PAIRS if mirror_depth else pairs) for i in pair]
    hips = [i for pair in _pairs(("hip",)) for i in pair]
    limbs = [i for pair in pairs for i in pair]
    # (F, L, 3) hip-relative world landmarks of the limbs, per labelling (limb pairs only).
    relative = [m.world[:, limbs] - m.world[:, hips].mean(1, keepdims=True) for m in states]
    pairwise = np.zeros((len(gaps), 2, 2))
    for s, previous in enumerate(states):
        for t, current in enumerate(states):
            cost = _jump_2d(previous.points, current.points, previous.confidence, indices, height)
            if mirror_depth:
                cost = cost + _axis_turn(previous.world, current.world)
            else:
                cost = cost + np.linalg.norm(relative[t][1:] - relative[s][:-1], axis=-1).mean(1) / METRIC_SCALE
            pairwise[:, s, t] = cost / gaps
    unary = np.zeros((len(gaps) + 1, 2))
    unary[:, 1] = SWAP_COST
    flags = viterbi(unary, pairwise).astype(bool)

    def pick(observed: np.ndarray, relabelled: np.ndarray) -> np.ndarray:
        return np.where(flags.reshape(-1, *[1] * (observed.ndim - 1)), relabelled, observed)

    out = Landmarks(
        pick(marks.points, swapped.points), pick(marks.confidence, swapped.confidence), pick(marks.world, swapped.world)
    )
    return out, flags


def repair_swaps(marks: Landmarks, height_px: float, frame_index: np.ndarray) -> tuple[Landmarks, Repair]:
    """Undo MediaPipe's left/right swaps (module docstring): the whole body first, then the legs, then the arms.

    Args:
        marks: the video's landmarks, F frames in time order.
        height_px: the person's height in pixels (the 2D jumps' scale).
        frame_index: (F,) source frame numbers (gaps between kept frames scale the jumps).

    Returns:
        the relabelled landmarks (new arrays) and which frames changed.
    """
    if len(frame_index) < 2:
        none = np.zeros(len(frame_index), dtype=bool)
        return marks, Repair(none, none, none)
    gaps = np.maximum(np.diff(np.asarray(frame_index, np.float64)), 1.0)
    marks, body = _decide(marks, BODY_PAIRS, True, height_px, gaps)
    marks, legs = _decide(marks, LEG_PAIRS, False, height_px, gaps)
    marks, arms = _decide(marks, ARM_PAIRS, False, height_px, gaps)
    return marks, Repair(body, legs, arms)
