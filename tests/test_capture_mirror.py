"""The front end's mirrored pass (flip test-time augmentation): un-mirroring and fusion."""

from __future__ import annotations

import numpy as np
import pytest
from capture_videos import real_frames, require_mediapipe

from pghm.capture.frontend import MIRROR_AGREEMENT, Detection, PoseEstimator, fuse_mirrored, unmirror
from pghm.capture.landmarks import LANDMARK_NAMES

WIDTH, HEIGHT = 96, 80
BLOB_SIGMA = 1.5
"""Pixels: the blob is symmetric and well inside the image, so its centroid is its centre."""


def other_side(name: str) -> str:
    """The landmark a mirror image of ``name`` looks like, by its name: left <-> right."""
    return name.replace("left", "@").replace("right", "left").replace("@", "right")


def blob_centroid(centre: np.ndarray, mirror: bool) -> np.ndarray:
    """Centroid (u, v) of a Gaussian blob drawn at ``centre`` in a W x H image, after mirroring the image."""
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH] + 0.5  # pixel centres at half-integers
    image = np.exp(-((cols - centre[0]) ** 2 + (rows - centre[1]) ** 2) / (2 * BLOB_SIGMA**2))
    if mirror:
        image = image[:, ::-1]
    return np.array([(image * cols).sum(), (image * rows).sum()]) / image.sum()


def random_detection(rng: np.random.Generator) -> Detection:
    points = rng.uniform([10, 10], [WIDTH - 10, HEIGHT - 10], (len(LANDMARK_NAMES), 2)).astype(np.float32)
    world = rng.normal(0, 0.3, (len(LANDMARK_NAMES), 3)).astype(np.float32)
    confidence = rng.uniform(0.2, 1.0, len(LANDMARK_NAMES)).astype(np.float32)
    mask = rng.random((HEIGHT, WIDTH)) > 0.5
    return Detection(points, confidence, world, mask, np.array([20.0, 10.0, 60.0, 70.0]))


def test_unmirror_puts_a_mirrored_frames_landmarks_back_where_they_were_drawn():
    """A perfect detector on the mirrored frame sees each drawn point at the mirrored blob's
    centroid, labelled as the other side (the person's left looks like a right), with the
    camera-aligned world x negated; un-mirroring must give back the drawing."""
    rng = np.random.default_rng(0)
    truth = random_detection(rng)
    seen = Detection(
        np.zeros_like(truth.landmarks_2d), np.zeros_like(truth.confidence), np.zeros_like(truth.landmarks_3d),
        truth.mask[:, ::-1], np.array([WIDTH - 60.0, 10.0, WIDTH - 20.0, 70.0]),
    )  # fmt: skip
    for index, name in enumerate(LANDMARK_NAMES):
        label = LANDMARK_NAMES.index(other_side(name))
        seen.landmarks_2d[label] = blob_centroid(truth.landmarks_2d[index], mirror=True)
        seen.landmarks_3d[label] = truth.landmarks_3d[index] * [-1, 1, 1]
        seen.confidence[label] = truth.confidence[index]
    back = unmirror(seen, WIDTH)
    np.testing.assert_allclose(back.landmarks_2d, truth.landmarks_2d, atol=1e-3)
    np.testing.assert_allclose(back.landmarks_3d, truth.landmarks_3d, atol=1e-6)
    np.testing.assert_array_equal(back.confidence, truth.confidence)
    np.testing.assert_array_equal(back.mask, truth.mask)
    np.testing.assert_allclose(back.box, truth.box)


def test_unmirror_twice_is_the_identity():
    detection = random_detection(np.random.default_rng(1))
    twice = unmirror(unmirror(detection, WIDTH), WIDTH)
    for field in ("landmarks_2d", "confidence", "landmarks_3d", "mask", "box"):
        np.testing.assert_allclose(getattr(twice, field), getattr(detection, field), atol=1e-5)


def traded(detection: Detection, parts: tuple[str, ...] | None, mirror_depth: bool = False) -> Detection:
    """``detection`` with the left and right landmarks of ``parts`` (None: all) relabelled, by name."""
    names = LANDMARK_NAMES if parts is None else {f"{side}_{part}" for part in parts for side in ("left", "right")}
    order = [LANDMARK_NAMES.index(other_side(name)) if name in names else i for i, name in enumerate(LANDMARK_NAMES)]
    world = detection.landmarks_3d[order] * ([1, 1, -1] if mirror_depth else 1)
    marks = (detection.landmarks_2d[order], detection.confidence[order], world.astype(np.float32))
    return Detection(*marks, detection.mask, detection.box)


def assert_same_landmarks(a: Detection, b: Detection) -> None:
    np.testing.assert_allclose(a.landmarks_2d, b.landmarks_2d, atol=1e-4)
    np.testing.assert_allclose(a.landmarks_3d, b.landmarks_3d, atol=1e-6)
    np.testing.assert_allclose(a.confidence, b.confidence, atol=1e-6)


def walker(rng: np.random.Generator) -> Detection:
    """A detection whose left and right sides are apart in 2D and along the world x axis (a body facing the camera)."""
    detection = random_detection(rng)
    for index, name in enumerate(LANDMARK_NAMES):
        side = 1 if name.startswith("left") or name == "mouth_left" else -1 if "right" in name else 0
        detection.landmarks_2d[index, 0] = WIDTH / 2 + side * rng.uniform(8, 20)
        detection.landmarks_3d[index, 0] = side * rng.uniform(0.1, 0.2)
    return detection


@pytest.mark.parametrize(
    "mistake",
    [
        "none",
        "legs",  # the mirrored pass traded the legs
        "arms",
        "body",  # ... or labelled the whole body the other way round (its depth mirrored)
    ],
)
def test_fusing_a_mirrored_pass_that_agrees_gives_the_original(mistake):
    found = walker(np.random.default_rng(2))
    mirrored = {
        "none": found,
        "legs": traded(found, ("knee", "ankle", "heel", "foot_index")),
        "arms": traded(found, ("elbow", "wrist", "pinky", "index", "thumb")),
        "body": traded(found, None, mirror_depth=True),
    }[mistake]
    assert_same_landmarks(fuse_mirrored(found, mirrored), found)


def test_fusion_is_the_confidence_weighted_mean():
    rng = np.random.default_rng(3)
    found = walker(rng)
    shift_2d, shift_3d = rng.normal(0, 0.5, found.landmarks_2d.shape), rng.normal(0, 0.02, found.landmarks_3d.shape)
    confidence = rng.uniform(0.1, 1.0, len(LANDMARK_NAMES)).astype(np.float32)
    mirrored = Detection(
        (found.landmarks_2d + shift_2d).astype(np.float32), confidence,
        (found.landmarks_3d + shift_3d).astype(np.float32), found.mask, found.box,
    )  # fmt: skip
    fused = fuse_mirrored(found, mirrored)
    c, c_m = found.confidence[:, None].astype(np.float64), confidence[:, None].astype(np.float64)
    np.testing.assert_allclose(fused.landmarks_2d, found.landmarks_2d + c_m / (c + c_m) * shift_2d, atol=1e-4)
    np.testing.assert_allclose(fused.landmarks_3d, found.landmarks_3d + c_m / (c + c_m) * shift_3d, atol=1e-5)
    np.testing.assert_allclose(fused.confidence, (found.confidence + confidence) / 2, atol=1e-6)
    np.testing.assert_array_equal(fused.mask, found.mask)


def test_a_mirrored_pass_that_followed_something_else_is_ignored():
    found = walker(np.random.default_rng(4))
    diagonal = np.hypot(*(found.box[2:] - found.box[:2]))
    elsewhere = found.landmarks_2d + 2 * MIRROR_AGREEMENT * diagonal
    mirrored = Detection(elsewhere.astype(np.float32), found.confidence, found.landmarks_3d, found.mask, found.box)
    assert_same_landmarks(fuse_mirrored(found, mirrored), found)


MEDIAN_AGREEMENT = 0.03
"""Fraction of the person's box diagonal: MediaPipe on a mirrored real frame, mirrored back, lands
within this of its landmarks on the frame itself (measured 0.009-0.012 on these frames; boxes within 0.02)."""


def test_mediapipe_on_a_mirrored_real_frame_agrees_once_mirrored_back():
    """The un-mirroring convention checked against MediaPipe itself: the same person, mirrored."""
    require_mediapipe()
    frames = real_frames(3)
    with PoseEstimator() as estimate:
        for image in frames:
            found = estimate(image)
            mirrored = estimate(np.ascontiguousarray(image[:, ::-1]))
            assert found is not None and mirrored is not None
            back = unmirror(mirrored, image.shape[1])
            diagonal = np.hypot(*(found.box[2:] - found.box[:2]))
            body = slice(11, None)  # shoulders down: the limbs whose labels must come back right
            distance = np.linalg.norm(back.landmarks_2d[body] - found.landmarks_2d[body], axis=-1)
            assert np.median(distance) < MEDIAN_AGREEMENT * diagonal
            # World landmarks: the left shoulder mirrored back is on the same side as found's.
            assert np.sign(back.landmarks_3d[11, 0] - back.landmarks_3d[12, 0]) == np.sign(
                found.landmarks_3d[11, 0] - found.landmarks_3d[12, 0]
            )
            np.testing.assert_allclose(back.box, found.box, atol=0.05 * diagonal)
