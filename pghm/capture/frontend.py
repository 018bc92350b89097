"""The front end: find the person in each frame, follow them through the video, measure them.

Per frame it gives the person's mask, MediaPipe's 33 pose landmarks in pixels with their
confidences, and its 33 metric "world" landmarks, all from MediaPipe's legacy
``solutions.pose.Pose(model_complexity=1, enable_segmentation=True)`` (mediapipe==0.10.14
ships the detector, landmark and segmentation models inside its wheel: nothing is
downloaded).

Tracking (:class:`PersonFinder`). Over a photograph of a room MediaPipe, run on the whole
frame, can miss the person or lock onto a person printed in the background. Its video mode
on the whole frame carries the person's region from frame to frame and so keeps them when
its detector alone would fail (a back turned to the camera over clutter); failing that, its
static-image mode searches a square around the previous frame's box (the person is then
large in the detector's input), and failing that its landmark model alone is given that
square (:class:`RegionPoseEstimator`: no detector). A detection only continues the track
when it is consistent with it: its centre within :data:`MAX_SHIFT` box diagonals of the
previous box's, its size within a factor :data:`MAX_SCALE_CHANGE` and each side within
:data:`MAX_SIDE_CHANGE`, all loosened for each frame the person has been lost. With no
track (the first frame, or after :data:`LOST_RESET` frames without the person), the whole
frame and three square windows along its long side are searched and the largest person
found starts the track: the person filmed is the one the camera frames. When MediaPipe's
detector sees no one (a back turned to the camera over clutter, for dozens of frames), OpenCV's
pedestrian detector proposes where upright people stand (:mod:`pghm.capture.pedestrians`),
and the landmark model alone, on each proposal's square, says whether a person is there.

Masks: MediaPipe's segmentation (thresholded at :data:`MASK_THRESHOLD`) can include other
people or clutter beside the person; only its connected components that hold one of the
person's visible landmarks are kept.

Two passes use this (:mod:`pghm.capture.pipeline`): :func:`track_person` on frames scaled
small (boxes only), then :class:`PersonInBox` on the subject's cropped images: the landmark
model on the square around each frame's box, for the masks and landmarks at the subject's
resolution.

Mirrored pass (flip test-time augmentation, pass 2): the landmark model also sees each frame
mirrored left-right; its landmarks, mirrored back (:func:`unmirror`), are averaged with the
person's by confidence (:func:`fuse_mirrored`), which cuts the landmarks' error a little
(docs/capture.md).
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from pghm.capture.pedestrians import PedestrianProposals, confirmed
from pghm.capture.swaps import ARM_PAIRS, BODY_PAIRS, LEG_PAIRS, Landmarks, left_right_axis, permutation, traded
from pghm.errors import PghmError

NUM_LANDMARKS = 33
"""MediaPipe's pose landmarks (``PoseLandmark`` numbering 0..32)."""

MODEL_COMPLEXITY = 1
"""MediaPipe's "full" landmark model, the one the 0.10.14 wheel ships."""

MIN_DETECTION_CONFIDENCE = 0.5
"""MediaPipe's person-detector and landmark-presence thresholds (its defaults)."""

MASK_THRESHOLD = 0.5
"""Segmentation probability above which a pixel is the person's."""

VISIBLE = 0.5
"""A landmark with visibility at least this is visible (it anchors mask components and boxes)."""

ROI_GROWTH = 1.6
"""The square searched around the previous box has this times the box's longest side."""

REGION_GROWTH = 1.25
"""The square given to the landmark model alone (:class:`RegionPoseEstimator`) has this times the
track's box's longest side (MediaPipe's own margin around a detected body); 1.5 found fewer
frames over clutter."""

MAX_SHIFT = 0.5
"""A detection continues the track if its box centre moved at most this many previous-box diagonals..."""

MAX_SCALE_CHANGE = 1.6
"""...and its box diagonal changed by at most this factor (per frame; both loosen with frames lost)."""

MAX_SIDE_CHANGE = 2.5
"""...and each of its sides by at most this factor: a box of the same diagonal but another shape (a
wide object beside a standing person) is another thing. Walking strides change a person's box
width by up to 1.46x between frames at 20 frames/s and 2.3x over four (bench_capture's walks)."""

MIRROR_AGREEMENT = 0.1
"""The mirrored pass's landmarks are fused only if their median 2D distance to the original's,
after aligning the limbs' labels, is at most this fraction of the person's box diagonal
(otherwise it followed something else, or the body's labels disagree: the original stands)."""

LOST_RESET = 30
"""Frames without the person after which the track is dropped and the largest person found starts a new one."""

INSTALL_HINT = "pip install 'pghm[capture]' (make setup installs it)"

Box = np.ndarray
"""(4,) float (x0, y0, x1, y1), pixels (docs/data.md: pixel centres at half-integers)."""


@dataclass
class Observations:
    """What the front end measured, for the kept frames only (F frames, subject-image pixels).

    Attributes:
        frame_index: (F,) int32 source video frame number of each kept frame.
        image_size: (H, W) of the subject images (after resize and crop).
        K: (3, 3) intrinsics in subject-image pixels if known (--fov / --focal), else None.
        landmarks_2d: (F, 33, 2) MediaPipe pose landmarks, pixels of the subject image.
        confidence: (F, 33) in [0, 1], MediaPipe visibility (times presence where given).
        landmarks_3d: (F, 33, 3) MediaPipe world landmarks: metres, origin between the hips,
            MediaPipe's axes (x right, y down, z away from the camera), camera-aligned.
        masks: (F, H, W) bool, the person's mask.
        frame_box: (4,) x0, y0, x1, y1 of the whole source frame in subject-image pixels
            (the subject images are a crop of it), or None when the images are the whole
            frame. With K unknown, the body fit's default field of view and principal point
            are the frame's, not the crop's.
    """

    frame_index: np.ndarray
    image_size: tuple[int, int]
    K: np.ndarray | None
    landmarks_2d: np.ndarray
    confidence: np.ndarray
    landmarks_3d: np.ndarray
    masks: np.ndarray
    frame_box: np.ndarray | None = None


@dataclass
class Detection:
    """The person found in one image (H x W).

    Attributes:
        landmarks_2d: (33, 2) pixels of the image.
        confidence: (33,) visibility (times presence where MediaPipe gives it).
        landmarks_3d: (33, 3) world landmarks, metres.
        mask: (H, W) bool.
        box: (4,) bounding box of the mask and the visible landmarks, clipped to the image.
    """

    landmarks_2d: np.ndarray
    confidence: np.ndarray
    landmarks_3d: np.ndarray
    mask: np.ndarray
    box: Box


@contextlib.contextmanager
def native_logs_silenced() -> Iterator[None]:
    """Send file descriptor 2 to /dev/null while Python's ``sys.stderr`` keeps writing to the terminal.

    MediaPipe's C++ side (absl, TFLite) prints "INFO: Created TensorFlow Lite XNNPACK
    delegate" and feedback-tensor warnings straight to descriptor 2, from its graph threads,
    at moments that do not follow the Python calls; its errors still arrive as Python
    exceptions. ``sys.stderr`` (progress bars, warnings, the CLI's messages) moves to a
    duplicate of the original descriptor for the duration, when it was writing to it.
    """
    sys.stderr.flush()
    saved = os.dup(2)
    python_stderr = sys.stderr
    try:
        on_descriptor = python_stderr.fileno() == 2
    except (AttributeError, OSError, ValueError):  # a captured or replaced sys.stderr
        on_descriptor = False
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
        if on_descriptor:
            sys.stderr = os.fdopen(os.dup(saved), "w", buffering=1, encoding=python_stderr.encoding, errors="replace")
        yield
    finally:
        if sys.stderr is not python_stderr:
            sys.stderr.close()
            sys.stderr = python_stderr
        os.dup2(saved, 2)
        os.close(saved)


class PoseEstimator:
    """MediaPipe Pose (legacy solution API) on an image or a square of it.

    Args:
        video: MediaPipe's video mode: each call's landmarks give the next call's region, so
            the detector runs only when the person is lost. Feed it whole frames of one
            video in order (its regions are in image coordinates). Otherwise static-image
            mode: detector then landmarks on every call, for squares that move between calls.
    """

    def __init__(self, video: bool = False) -> None:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # protobuf deprecation warnings at import
                from mediapipe.python.solutions import pose
        except ImportError:
            raise PghmError(f"pghm capture needs mediapipe: {INSTALL_HINT}") from None
        self._pose = pose.Pose(
            static_image_mode=not video,
            model_complexity=MODEL_COMPLEXITY,
            enable_segmentation=True,
            min_detection_confidence=MIN_DETECTION_CONFIDENCE,
            min_tracking_confidence=MIN_DETECTION_CONFIDENCE,
        )

    def close(self) -> None:
        self._pose.close()

    def __enter__(self) -> PoseEstimator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __call__(self, image: np.ndarray, roi: Box | None = None) -> Detection | None:
        """The person in ``image`` (H, W, 3) uint8, searched in ``roi`` (None: everywhere); None if not found."""
        height, width = image.shape[:2]
        x0, y0, x1, y1 = _pixel_rect(roi, width, height) if roi is not None else (0, 0, width, height)
        if x1 - x0 < 2 or y1 - y0 < 2:
            return None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = self._pose.process(np.ascontiguousarray(image[y0:y1, x0:x1]))
        return _detection(result, (height, width), (x0, y0, x1, y1))


REGION_GRAPH = """
input_stream: "IMAGE:image"
input_stream: "ROI:roi"
output_stream: "LANDMARKS:pose_landmarks"
output_stream: "WORLD_LANDMARKS:pose_world_landmarks"
output_stream: "SEGMENTATION_MASK:segmentation_mask"
input_side_packet: "MODEL_COMPLEXITY:model_complexity"
input_side_packet: "ENABLE_SEGMENTATION:enable_segmentation"
node {
  calculator: "PoseLandmarkByRoiCpu"
  input_stream: "IMAGE:image"
  input_stream: "ROI:roi"
  output_stream: "LANDMARKS:pose_landmarks"
  output_stream: "AUXILIARY_LANDMARKS:auxiliary_landmarks"
  output_stream: "WORLD_LANDMARKS:pose_world_landmarks"
  output_stream: "SEGMENTATION_MASK:segmentation_image"
  input_side_packet: "MODEL_COMPLEXITY:model_complexity"
  input_side_packet: "ENABLE_SEGMENTATION:enable_segmentation"
}
node {
  calculator: "FromImageCalculator"
  input_stream: "IMAGE:segmentation_image"
  output_stream: "IMAGE_CPU:segmentation_mask"
}
"""
"""MediaPipe's pose landmark subgraph alone (the one its Pose solution runs after its detector, or
on the region its previous landmarks give in video mode), fed a region chosen by the caller."""


class RegionPoseEstimator:
    """MediaPipe's pose landmark model on a given square of an image, without its person detector.

    MediaPipe's detector finds people by their face and upper body, so it misses a back turned
    to the camera; its landmark model, given the region where the person stands, does not (on
    bench_capture's back views over a garage, from the true boxes: 98 of 100 frames against the
    Pose solution's 54). The landmark model still says whether a person is in the region (its
    presence flag): an empty square gives None. Regions come from the track (the previous
    frame's box in :class:`PersonFinder`, the frame's own in :class:`PersonInBox`), never from a
    guess over the whole frame.
    """

    def __init__(self) -> None:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                from google.protobuf import text_format
                from mediapipe.framework import calculator_pb2
                from mediapipe.python.solution_base import PacketDataType, SolutionBase
        except ImportError:
            raise PghmError(f"pghm capture needs mediapipe: {INSTALL_HINT}") from None
        self._graph = SolutionBase(
            graph_config=text_format.Parse(REGION_GRAPH, calculator_pb2.CalculatorGraphConfig()),
            side_inputs={"model_complexity": MODEL_COMPLEXITY, "enable_segmentation": True},
            outputs=["pose_landmarks", "pose_world_landmarks", "segmentation_mask"],
            stream_type_hints={"roi": PacketDataType.PROTO},
        )

    def close(self) -> None:
        self._graph.close()

    def __enter__(self) -> RegionPoseEstimator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __call__(self, image: np.ndarray, square: Box) -> Detection | None:
        """The person in the (axis-aligned) ``square`` of ``image`` (H, W, 3) uint8; None if the model finds none.

        The square may reach past the image (MediaPipe pads it)."""
        from mediapipe.framework.formats import rect_pb2

        height, width = image.shape[:2]
        centre, side = (square[:2] + square[2:]) / 2, square[2] - square[0]
        roi = rect_pb2.NormalizedRect(
            x_center=centre[0] / width, y_center=centre[1] / height, width=side / width, height=side / height
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = self._graph.process({"image": np.ascontiguousarray(image), "roi": roi})
        return _detection(result, (height, width), (0, 0, width, height))


def _detection(result, image_size: tuple[int, int], rect: tuple[int, int, int, int]) -> Detection | None:
    """A MediaPipe pose result on the pixels ``rect`` (x0, y0, x1, y1) of an image of ``image_size``
    (H, W) as a :class:`Detection` in the image's pixels; None without landmarks, mask or box."""
    if result.pose_landmarks is None or result.segmentation_mask is None:
        return None
    height, width = image_size
    x0, y0, x1, y1 = rect
    points = result.pose_landmarks.landmark
    normalised = np.array([[p.x, p.y] for p in points], dtype=np.float64)
    landmarks_2d = normalised * [x1 - x0, y1 - y0] + [x0, y0]
    visibility = np.array([p.visibility for p in points], dtype=np.float32)
    presence = np.array([p.presence for p in points], dtype=np.float32)
    # The legacy graph leaves presence at 0 (unset); use it only where it is given.
    confidence = visibility * presence if presence.any() else visibility
    world = np.array([[p.x, p.y, p.z] for p in result.pose_world_landmarks.landmark], dtype=np.float32)
    mask = np.zeros((height, width), dtype=bool)
    segmentation = result.segmentation_mask >= MASK_THRESHOLD
    mask[y0:y1, x0:x1] = person_components(segmentation, landmarks_2d - [x0, y0], confidence)
    box = detection_box(mask, landmarks_2d, confidence)
    if box is None:
        return None
    return Detection(landmarks_2d.astype(np.float32), np.clip(confidence, 0, 1), world, mask, box)


def person_components(mask: np.ndarray, landmarks_2d: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """The connected components (8-neighbour) of ``mask`` (H, W) bool that hold a visible landmark.

    Landmarks are (33, 2) pixels of the mask's image; a landmark lands in the pixel that
    contains it. With no visible landmark on the mask, its largest component is kept.
    """
    import cv2

    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if count <= 2:  # background plus at most one component
        return mask
    height, width = mask.shape
    cols, rows = np.floor(landmarks_2d[:, 0]).astype(int), np.floor(landmarks_2d[:, 1]).astype(int)
    inside = (confidence >= VISIBLE) & (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    touched = np.unique(labels[rows[inside], cols[inside]])
    touched = touched[touched > 0]
    if len(touched) == 0:
        touched = np.array([1 + np.argmax(stats[1:, cv2.CC_STAT_AREA])])
    return np.isin(labels, touched)


def detection_box(mask: np.ndarray, landmarks_2d: np.ndarray, confidence: np.ndarray) -> Box | None:
    """(4,) box around the mask's pixels and the visible landmarks, clipped to the image; None on an empty mask."""
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    if len(rows) == 0:
        return None
    height, width = mask.shape
    x0, x1, y0, y1 = cols[0], cols[-1] + 1.0, rows[0], rows[-1] + 1.0
    visible = landmarks_2d[confidence >= VISIBLE]
    if len(visible):
        x0, y0 = min(x0, visible[:, 0].min()), min(y0, visible[:, 1].min())
        x1, y1 = max(x1, visible[:, 0].max()), max(y1, visible[:, 1].max())
    return np.array([max(0.0, x0), max(0.0, y0), min(width, x1), min(height, y1)], dtype=np.float64)


def _pixel_rect(box: Box, width: int, height: int) -> tuple[int, int, int, int]:
    """Whole pixels (x0, y0, x1, y1) covering ``box``, clipped to the image."""
    x0, y0 = max(0, int(np.floor(box[0]))), max(0, int(np.floor(box[1])))
    return x0, y0, min(width, int(np.ceil(box[2]))), min(height, int(np.ceil(box[3])))


def search_square(box: Box, growth: float = ROI_GROWTH) -> Box:
    """The square centred on ``box`` with ``growth`` times its longest side (not clipped)."""
    centre = (box[:2] + box[2:]) / 2
    half = growth * max(box[2] - box[0], box[3] - box[1]) / 2
    return np.concatenate([centre - half, centre + half])


def consistent(box: Box, previous: Box, frames_lost: int) -> bool:
    """Whether ``box`` continues a track last seen at ``previous``, ``frames_lost`` frames ago.

    |c - c_prev| <= MAX_SHIFT d_prev (1 + lost), 1 / s <= d / d_prev <= s and, for each side k of the
    box, 1 / t <= k / k_prev <= t, with s = MAX_SCALE_CHANGE ** (1 + lost), t = MAX_SIDE_CHANGE ** (1 + lost),
    c the box centre, d its diagonal.
    """
    sides, previous_sides = box[2:] - box[:2], previous[2:] - previous[:2]
    diagonal, previous_diagonal = np.hypot(*sides), np.hypot(*previous_sides)
    shift = np.hypot(*((box[:2] + box[2:]) / 2 - (previous[:2] + previous[2:]) / 2))
    slack = 1 + frames_lost
    ratio = diagonal / max(previous_diagonal, 1e-9)
    side_ratios = sides / np.maximum(previous_sides, 1e-9)
    near = shift <= MAX_SHIFT * previous_diagonal * slack
    similar = MAX_SCALE_CHANGE ** (-slack) <= ratio <= MAX_SCALE_CHANGE**slack
    shaped = bool(np.all((MAX_SIDE_CHANGE ** (-slack) <= side_ratios) & (side_ratios <= MAX_SIDE_CHANGE**slack)))
    return bool(near and similar and shaped)


def _windows(width: int, height: int) -> list[Box]:
    """Three squares of side min(W, H) at the start, middle and end of the frame's long side."""
    side = min(width, height)
    starts = np.linspace(0, max(width, height) - side, 3)
    if width >= height:
        return [np.array([s, 0, s + side, side], dtype=np.float64) for s in starts]
    return [np.array([0, s, side, s + side], dtype=np.float64) for s in starts]


def _area(box: Box) -> float:
    return float((box[2] - box[0]) * (box[3] - box[1]))


class PersonFinder:
    """The tracked person in each frame of one sequence of equally sized frames, fed in order (pass 1).

    Holds three MediaPipe instances: one in video mode fed every whole frame (it follows the
    person from their landmarks through frames its detector alone misses), one in static-image
    mode for the squares around the previous box and the windows searched to start a track, and
    the landmark model alone (:class:`RegionPoseEstimator`) for the square around the previous
    box when both fail, and for OpenCV's pedestrian proposals
    (:class:`~pghm.capture.pedestrians.PedestrianProposals`) when MediaPipe finds no one.
    """

    def __init__(self) -> None:
        self.video = PoseEstimator(video=True)
        self.still = PoseEstimator(video=False)
        self.region = RegionPoseEstimator()
        self.pedestrians = PedestrianProposals()

    def close(self) -> None:
        self.video.close()
        self.still.close()
        self.region.close()

    def __enter__(self) -> PersonFinder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __call__(self, image: np.ndarray, previous: Box | None, frames_lost: int) -> Detection | None:
        """The person in ``image`` given their box ``previous`` seen ``frames_lost`` frames ago (None: no track).

        With a track: video mode on the whole frame, then the detector on the square around
        ``previous``, then the landmark model alone on it, then on each pedestrian proposal's
        square; a detection counts only if :func:`consistent` with the track. Without: video
        mode on the whole frame and three windows, else the proposals the landmark model
        confirms; the largest person found (see the module docstring).
        """
        followed = self.video(image)
        if previous is not None:
            if followed is not None and consistent(followed.box, previous, frames_lost):
                return followed
            found = self.still(image, search_square(previous))
            if found is None or not consistent(found.box, previous, frames_lost):
                found = self.region(image, search_square(previous, REGION_GROWTH))
            if found is not None and consistent(found.box, previous, frames_lost):
                return found
            return next((d for d in self._proposed(image) if consistent(d.box, previous, frames_lost)), None)
        height, width = image.shape[:2]
        candidates = [followed, *(self.still(image, window) for window in _windows(width, height))]
        candidates = [c for c in candidates if c is not None] or list(self._proposed(image))
        return max(candidates, key=lambda c: _area(c.box)) if candidates else None

    def _proposed(self, image: np.ndarray) -> Iterator[Detection]:
        """The people the landmark model confirms on the squares of OpenCV's pedestrian proposals,
        best proposal first (lazily: a track takes the first that continues it)."""
        for proposal in self.pedestrians(image):
            detection = self.region(image, search_square(proposal, REGION_GROWTH))
            if confirmed(None if detection is None else detection.box, proposal):
                yield detection


class PersonInBox:
    """The person measured in a box known to hold them (pass 2: each frame's box from pass 1).

    The landmark model alone on the square around the box (:class:`RegionPoseEstimator`), the
    detector on a wider square if it finds no one there; the answer counts only if
    :func:`consistent` with the box. Frames are independent: no temporal filter, no state
    carried from frame to frame. With ``mirrored``, the landmark model also sees the frame
    mirrored left-right (the square mirrored with it), and its landmarks, mirrored back, are
    fused with the person's (:func:`fuse_mirrored`: flip test-time augmentation).

    Given the track's box, rather than the region video mode carries from its own previous
    landmarks, the landmarks drift less in clutter: on bench_capture's garage video PA-MPJPE 54.7
    -> 47.1 mm (docs/capture.md, "Pass 2: the person in the track's box").
    """

    def __init__(self, mirrored: bool = False) -> None:
        self.region = RegionPoseEstimator()
        self.still = PoseEstimator(video=False)
        self.mirror = RegionPoseEstimator() if mirrored else None

    def close(self) -> None:
        self.region.close()
        self.still.close()
        if self.mirror is not None:
            self.mirror.close()

    def __enter__(self) -> PersonInBox:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __call__(self, image: np.ndarray, box: Box) -> Detection | None:
        """The person in ``image`` (H, W, 3) uint8 whose box is about ``box``; None if not found there."""
        square = search_square(box, REGION_GROWTH)
        found = self.region(image, square)
        if found is None or not consistent(found.box, box, frames_lost=0):
            found = self.still(image, search_square(box))
            if found is None or not consistent(found.box, box, frames_lost=0):
                return None
        if self.mirror is None:
            return found
        width = image.shape[1]
        mirrored_square = np.array([width - square[2], square[1], width - square[0], square[3]])
        mirrored = self.mirror(np.ascontiguousarray(image[:, ::-1]), mirrored_square)
        return found if mirrored is None else fuse_mirrored(found, unmirror(mirrored, width))


MIRROR_ORDER = permutation(BODY_PAIRS)
"""(33,) landmark index -> the index of its mirror image (left <-> right; the nose stays)."""


def unmirror(detection: Detection, width: int) -> Detection:
    """A detection made on an image mirrored left-right (width ``width``), as seen in the original image.

    Mirroring maps pixel x to W - x (pixel centres at half-integers, so column j goes to
    W - 1 - j), makes the person's left side look like a right side, and negates the
    camera-aligned x of the world landmarks. Undone: x -> W - x, every left/right pair
    traded (:data:`MIRROR_ORDER`), world x negated, the mask mirrored back.
    """
    points = detection.landmarks_2d[MIRROR_ORDER].copy()
    points[:, 0] = width - points[:, 0]
    world = detection.landmarks_3d[MIRROR_ORDER].copy()
    world[:, 0] *= -1
    box = np.array([width - detection.box[2], detection.box[1], width - detection.box[0], detection.box[3]])
    return Detection(points, detection.confidence[MIRROR_ORDER].copy(), world, detection.mask[:, ::-1].copy(), box)


def _traded(detection: Detection, pairs: list[tuple[int, int]], mirror_depth: bool = False) -> Detection:
    """``detection`` with ``pairs`` trading labels (:func:`pghm.capture.swaps.traded`)."""
    one = Landmarks(detection.landmarks_2d[None], detection.confidence[None], detection.landmarks_3d[None])
    marks = traded(one, pairs, mirror_depth)
    return Detection(marks.points[0], marks.confidence[0], marks.world[0], detection.mask, detection.box)


def _median_distance(a: Detection, b: Detection, indices: list[int]) -> float:
    return float(np.median(np.linalg.norm(a.landmarks_2d[indices] - b.landmarks_2d[indices], axis=-1)))


def fuse_mirrored(found: Detection, mirrored: Detection) -> Detection:
    """The landmarks of ``found`` averaged with those of ``mirrored`` (already mirrored back), by confidence.

    The mirrored pass labels the body on its own, so its labels are first aligned with
    ``found``'s (the body fit's swap repair then decides the labelling over time): the whole
    body traded, depth mirrored, when its world landmarks' left-right axis points against
    ``found``'s (:func:`pghm.capture.swaps.left_right_axis`); then per pair of limbs (legs,
    arms) traded when that brings its 2D points closer to ``found``'s. If the two still disagree (median 2D distance
    over :data:`MIRROR_AGREEMENT` of the box diagonal), ``found`` is returned unchanged.
    Each landmark is then x = (c x + c' x') / (c + c'), likewise the world landmarks, with
    confidence (c + c') / 2; the mask and box stay ``found``'s.
    """
    if (left_right_axis(found.landmarks_3d) * left_right_axis(mirrored.landmarks_3d)).sum() < 0:
        mirrored = _traded(mirrored, BODY_PAIRS, mirror_depth=True)
    for pairs in (LEG_PAIRS, ARM_PAIRS):
        indices = [i for pair in pairs for i in pair]
        other = _traded(mirrored, pairs)
        if _median_distance(other, found, indices) < _median_distance(mirrored, found, indices):
            mirrored = other
    diagonal = float(np.hypot(*(found.box[2:] - found.box[:2])))
    if _median_distance(mirrored, found, list(range(NUM_LANDMARKS))) > MIRROR_AGREEMENT * diagonal:
        return found
    c, c_m = found.confidence.astype(np.float64), mirrored.confidence.astype(np.float64)
    total = c + c_m
    share = np.divide(c, total, out=np.full_like(total, 0.5), where=total > 0)[:, None]
    return Detection(
        (share * found.landmarks_2d + (1 - share) * mirrored.landmarks_2d).astype(np.float32),
        (total / 2).astype(np.float32),
        (share * found.landmarks_3d + (1 - share) * mirrored.landmarks_3d).astype(np.float32),
        found.mask,
        found.box,
    )


@dataclass
class Track:
    """The person's box in each frame where they were found (pass 1).

    Attributes:
        frame_index: (F,) int source frame numbers where the person was found.
        boxes: (F, 4) their boxes, pixels of the frames searched.
        lost: source frame numbers read where the person was not found.
    """

    frame_index: np.ndarray
    boxes: np.ndarray
    lost: list[int]

    @property
    def frames_read(self) -> int:
        return len(self.frame_index) + len(self.lost)


def track_person(frames: Iterable[tuple[int, np.ndarray]], on_frame: Callable[[], None] | None = None) -> Track:
    """Follow one person through ``frames`` ((source frame number, (H, W, 3) uint8) pairs of one size)."""
    indices, boxes, lost = [], [], []
    previous, frames_lost = None, 0
    with PersonFinder() as find:
        for index, image in frames:
            found = find(image, previous, frames_lost)
            if found is None:
                lost.append(int(index))
                frames_lost += 1
                if frames_lost >= LOST_RESET:
                    previous, frames_lost = None, 0
            else:
                indices.append(int(index))
                boxes.append(found.box)
                previous, frames_lost = found.box, 0
            if on_frame is not None:
                on_frame()
    return Track(np.array(indices, dtype=np.int64), np.array(boxes, dtype=np.float64).reshape(-1, 4), lost)
