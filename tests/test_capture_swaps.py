"""Left/right swap repair (pghm.capture.swaps) and the unknown-focal fallback on a crop.

The truth for the swaps: the landmarks of a synthetic Anny walk (the body-fit round trip's
observations, exact labels), in which frames are relabelled the way MediaPipe errs: the
whole body mirrored (labels traded, world depth negated), or the legs traded. The repair
must find exactly those frames and give back the original landmarks.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_capture_bodyfit import FRAMES, synthetic

from pghm.capture.bodyfit import default_intrinsics
from pghm.capture.config import CaptureConfig
from pghm.capture.crop import Region, crop_intrinsics, frame_box
from pghm.capture.frontend import Observations
from pghm.capture.landmarks import LANDMARK_NAMES
from pghm.capture.swaps import BODY_PAIRS, LEG_PAIRS, Landmarks, permutation, repair_swaps, viterbi


def walk_landmarks() -> tuple[Landmarks, float]:
    observations, truth = synthetic("walk", 5)
    marks = Landmarks(observations.landmarks_2d, observations.confidence, observations.landmarks_3d)
    return marks, float(truth.height_px.mean())


def relabel(marks: Landmarks, frames: list[int], pairs: list[tuple[int, int]], mirror_depth: bool) -> Landmarks:
    points, confidence, world = marks.points.copy(), marks.confidence.copy(), marks.world.copy()
    order = permutation(pairs)
    for f in frames:
        points[f], confidence[f], world[f] = points[f, order], confidence[f, order], world[f, order]
        if mirror_depth:
            world[f, :, 2] *= -1
    return Landmarks(points, confidence, world)


def test_every_left_landmark_pairs_with_its_right() -> None:
    names = {LANDMARK_NAMES[i]: LANDMARK_NAMES[j] for i, j in BODY_PAIRS}
    assert len(BODY_PAIRS) == 16  # MediaPipe's 33 landmarks: the nose and 16 pairs
    for left, right in names.items():
        assert left.replace("left", "right") == right
    order = permutation(BODY_PAIRS)
    assert (order[order] == np.arange(len(LANDMARK_NAMES))).all() and order[0] == 0


def test_viterbi_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    unary, pairwise = rng.uniform(0, 1, (7, 2)), rng.uniform(0, 1, (6, 2, 2))
    paths = np.array(np.meshgrid(*[[0, 1]] * 7, indexing="ij")).reshape(7, -1).T
    costs = [unary[np.arange(7), p].sum() + pairwise[np.arange(6), p[:-1], p[1:]].sum() for p in paths]
    assert viterbi(unary, pairwise).tolist() == paths[int(np.argmin(costs))].tolist()


@pytest.mark.parametrize("body_frames,leg_frames", [([9, 10, 11], []), ([], [4]), ([], [15, 16]), ([3], [18, 19])])
def test_constructed_swaps_are_undone(body_frames: list[int], leg_frames: list[int]) -> None:
    marks, height = walk_landmarks()
    swapped = relabel(relabel(marks, body_frames, BODY_PAIRS, True), leg_frames, LEG_PAIRS, False)
    repaired, repair = repair_swaps(swapped, height, np.arange(FRAMES))
    assert np.flatnonzero(repair.body).tolist() == body_frames
    assert np.flatnonzero(repair.legs).tolist() == leg_frames
    assert not repair.arms.any()
    np.testing.assert_allclose(repaired.points, marks.points)
    np.testing.assert_allclose(repaired.confidence, marks.confidence)
    np.testing.assert_allclose(repaired.world, marks.world, atol=1e-7)


def test_correct_labels_are_kept() -> None:
    marks, height = walk_landmarks()
    _, repair = repair_swaps(marks, height, np.arange(0, 2 * FRAMES, 2))
    assert not (repair.body.any() or repair.legs.any() or repair.arms.any())


def test_unknown_focal_uses_the_source_frame_not_the_crop() -> None:
    """The fallback equals --fov's intrinsics of the whole frame carried through the crop."""
    width, height, fov = 1080, 1920, 60.0
    region, out_size = Region(300, 500, 420, 900), (512, 239)
    expected = crop_intrinsics(CaptureConfig(fov_deg=fov).source_intrinsics(width, height), region, out_size)
    observations = Observations(
        np.arange(1, dtype=np.int32),
        out_size,
        None,
        np.zeros((1, 33, 2), np.float32),
        np.zeros((1, 33), np.float32),
        np.zeros((1, 33, 3), np.float32),
        np.zeros((1, *out_size), bool),
        frame_box(region, width, height, out_size),
    )
    focal, principal = default_intrinsics(observations, fov)
    np.testing.assert_allclose(focal, expected[1, 1], rtol=1e-5)  # the frame's long side is its height
    np.testing.assert_allclose(principal, expected[:2, 2], atol=1e-3)
    observations.frame_box = None  # images that are the whole frame: their own size and centre
    focal, principal = default_intrinsics(observations, fov)
    np.testing.assert_allclose(focal, 0.5 * 512 / np.tan(np.radians(fov) / 2), rtol=1e-6)
    np.testing.assert_allclose(principal, [239 / 2, 256])
