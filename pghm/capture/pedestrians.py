"""Where a standing person may be when MediaPipe's detector sees no one: OpenCV's people detector.

MediaPipe's person detector finds people by the face and upper body, so a walker with their
back to the camera over a busy photograph can go unseen for dozens of frames (bench_capture's
held-out garage: frames 0-32, a third of the video, lost). Its landmark model, given the square
where the person stands, finds them (:class:`~pghm.capture.frontend.RegionPoseEstimator`); what
is missing is the square. OpenCV's HOG people detector (Dalal & Triggs; its linear SVM ships
inside OpenCV, which mediapipe installs: nothing new, nothing downloaded) sees a body's outline
from any side. Its boxes are only proposals: each is handed to the landmark model, and a
proposal counts only if the landmark model finds a person there whose box agrees with it
(:func:`confirmed`). They seed a track; the track is then followed as any other.
"""

from __future__ import annotations

import numpy as np

MIN_SCORE = 0.3
"""SVM margin below which a HOG window is not proposed (OpenCV's default threshold is 0)."""

MAX_PROPOSALS = 3
"""The best-scoring windows handed to the landmark model, per frame."""

WIN_STRIDE = (8, 8)
PADDING = (16, 16)
"""OpenCV's detectMultiScale sampling (its pedestrian sample's settings)..."""

SCALE_STEP = 1.1
"""...but a coarser pyramid than its 1.05: 0.035 s a 512 x 384 frame instead of 0.085, and the same
walker found on bench_capture's held-out garage."""

MIN_AGREEMENT = 0.5
"""A proposal is confirmed when the landmark model's person box overlaps it by at least this IoU
(HOG's windows hold a margin around the body: the walkers of bench_capture's garage, 0.54-0.74;
the landmark model's answers on the motorcycle's windows, 0.34-0.43)..."""

MIN_UPRIGHT = 1.5
"""...and that box is at least this many times as tall as wide, as HOG's upright pedestrians are
(walkers 1.8-2.8; the motorcycle's answers 0.8-1.0)."""


def box_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (4,) x0, y0, x1, y1 boxes."""
    sides = np.clip(np.minimum(a[2:], b[2:]) - np.maximum(a[:2], b[:2]), 0, None)
    inter = float(sides.prod())
    union = float((a[2:] - a[:2]).prod() + (b[2:] - b[:2]).prod()) - inter
    return inter / union if union > 0 else 0.0


class PedestrianProposals:
    """(4,) x0, y0, x1, y1 boxes of upright people in an (H, W, 3) uint8 image, best first
    (OpenCV's HOG descriptor and linear SVM; gradients of the strongest colour channel)."""

    def __init__(self) -> None:
        import cv2

        self._hog = cv2.HOGDescriptor()
        self._hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())

    def __call__(self, image: np.ndarray) -> list[np.ndarray]:
        window_width, window_height = self._hog.winSize
        if image.shape[0] < window_height or image.shape[1] < window_width:
            return []  # no room for one window (and OpenCV's detector crashes on such an image)
        rects, scores = self._hog.detectMultiScale(
            np.ascontiguousarray(image), winStride=WIN_STRIDE, padding=PADDING, scale=SCALE_STEP
        )
        if len(rects) == 0:
            return []
        scores = np.ravel(scores)
        order = np.argsort(-scores)
        boxes = [np.array([x, y, x + w, y + h], dtype=np.float64) for x, y, w, h in np.asarray(rects)[order]]
        return [box for box, score in zip(boxes, scores[order]) if score >= MIN_SCORE][:MAX_PROPOSALS]


def confirmed(found: np.ndarray | None, proposal: np.ndarray) -> bool:
    """Whether the box of the person the landmark model ``found`` on a proposal's square (None:
    no one) is the person proposed."""
    if found is None:
        return False
    width, height = found[2:] - found[:2]
    return box_iou(found, proposal) >= MIN_AGREEMENT and height >= MIN_UPRIGHT * width
