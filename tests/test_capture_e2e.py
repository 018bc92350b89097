"""``pghm capture`` end to end on a short synthetic walk, against the generator's truth.

The walk (:mod:`pghm.synth.video`) is an H.264 video over a plain graded background;
the command runs as a user runs it (the CLI, default options but a test split that a short
video can fill). The truth is mapped into the subject's pixels independently of the
pipeline: the true masks cropped to meta.json's region and resized, the joints compared
root-relative and Procrustes-aligned in each camera's own coordinates (no crop involved).
benchmarks/bench_capture.py measures the same on 512-px videos over photographs too.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from capture_videos import require_mediapipe
from PIL import Image

from pghm.cli.main import main
from pghm.subject import Subject, check, image_name, read_mask
from pghm.synth.video import graded_background, render_walk_video, walk_config
from pghm.train.data import ESTIMATOR_ROTATION_SIGMA, ESTIMATOR_TRANSLATION_SIGMA, TrainingData

pytestmark = pytest.mark.gl

FRAMES = 16
WIDTH, HEIGHT = 384, 288
TEXTURE = 256
SEED = 3
BACKGROUND = ((126, 134, 142), (170, 158, 138))
"""A grey-blue wall fading to a beige floor."""
TEST_EVERY = 4

IOU_FLOOR = 0.93
"""Mean mask IoU over the video (a dropped frame counts 0). Measured 0.965 (frames 0.956 to
0.975, none dropped): the floor leaves 0.035. The target on 512-px plain videos is 0.95;
a 384-px video has more edge pixels per area."""
PA_MPJPE_FLOOR_MM = 75.0
"""Measured 56.9 mm (MPJPE 62.1 mm) with the body fit of c08f136 (62.5 mm with 135e742): the
floor leaves 18 mm for the fit's tuning. The target (512-px videos, bench_capture) is 50 mm."""
MIN_KEPT = FRAMES - 2
"""The person is in every frame, on a plain background: at most two frames may be lost."""


@pytest.fixture(scope="module")
def captured(tmp_path_factory):
    require_mediapipe()
    work = tmp_path_factory.mktemp("capture_e2e")
    video, out = work / "walk.mp4", work / "subject"
    config = walk_config(FRAMES, WIDTH, HEIGHT, TEXTURE)
    truth = render_walk_video(config, SEED, video, graded_background(*BACKGROUND, WIDTH, HEIGHT))
    status = main(["capture", str(video), "--out", str(out), "--test-every", str(TEST_EVERY)])
    return truth, out, status


def true_masks_in_subject(truth, subject: Subject) -> np.ndarray:
    """(F, H', W') bool: every true mask cut to the capture's region and resized to the images (nearest)."""
    crop = subject.meta["crop"]
    box = (crop["x"], crop["y"], crop["x"] + crop["width"], crop["y"] + crop["height"])
    size = (int(subject.arrays.width[0]), int(subject.arrays.height[0]))
    masks = [Image.fromarray(m.astype(np.uint8) * 255).crop(box) for m in truth.masks]
    return np.stack([np.asarray(m.resize(size, Image.Resampling.NEAREST)) > 0 for m in masks])


def true_mattes_in_subject(truth, subject: Subject) -> np.ndarray:
    """(F, H', W') float: every true alpha matte cut to the capture's region and resized to the images (bilinear)."""
    crop = subject.meta["crop"]
    box = (crop["x"], crop["y"], crop["x"] + crop["width"], crop["y"] + crop["height"])
    size = (int(subject.arrays.width[0]), int(subject.arrays.height[0]))
    mattes = [Image.fromarray(c.astype(np.float32) / 255, mode="F") for c in truth.coverage]
    return np.stack([np.asarray(m.resize(size, Image.Resampling.BILINEAR, box=box)) for m in mattes])


def captured_masks(subject_dir, count: int) -> np.ndarray:
    return np.stack([read_mask(subject_dir / "masks" / image_name(i)) > 0.5 for i in range(count)])


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of boolean masks along the last two axes (broadcasting)."""
    return (a & b).sum((-2, -1)) / np.maximum((a | b).sum((-2, -1)), 1)


def test_capture_writes_a_subject_the_checker_accepts(captured):
    truth, out, status = captured
    assert status == 0
    assert check(out) == []
    subject = Subject.open(out)
    assert len(subject) >= MIN_KEPT
    assert subject.split("test") and subject.split("train")
    meta = json.loads((out / "meta.json").read_text())
    assert meta["input"] == "walk.mp4"
    assert meta["counts"]["frames_read"] == FRAMES
    # The capture states its poses' error, wider than the synthetic data's: the fit's prior on the
    # pose corrections (and test-time refinement) then lets them move that far.
    rotation_sigma, translation_sigma = TrainingData(out).pose_sigmas()
    assert float(rotation_sigma.min()) > 3 * ESTIMATOR_ROTATION_SIGMA
    assert float(translation_sigma.min()) > 3 * ESTIMATOR_TRANSLATION_SIGMA


def test_frame_index_is_the_source_frame(captured):
    """Each captured mask matches the true mask of its frame_index better than any other frame's."""
    truth, out, _ = captured
    subject = Subject.open(out)
    frames = np.asarray(subject.arrays.frame_index)
    assert np.all(np.diff(frames) > 0) and frames.min() >= 0 and frames.max() < FRAMES
    dropped = json.loads((out / "meta.json").read_text())["counts"]["dropped_frames"]
    assert sorted(set(range(FRAMES)) - set(frames.tolist())) == sorted(dropped)
    overlaps = iou(captured_masks(out, len(frames))[:, None], true_masks_in_subject(truth, subject)[None])
    assert np.array_equal(overlaps.argmax(axis=1), frames)


def test_mask_iou_floor(captured):
    truth, out, _ = captured
    subject = Subject.open(out)
    frames = np.asarray(subject.arrays.frame_index)
    per_frame = np.zeros(FRAMES)
    per_frame[frames] = iou(captured_masks(out, len(frames)), true_masks_in_subject(truth, subject)[frames])
    assert per_frame.mean() >= IOU_FLOOR


def test_matte_is_nearer_the_true_alpha_than_its_mask(captured):
    """The stored matte (colour-model alpha on the outline) is nearer the generator's coverage than
    the binary mask it came from (its pixels at least half covered)."""
    truth, out, _ = captured
    subject = Subject.open(out)
    frames = np.asarray(subject.arrays.frame_index)
    mattes = np.stack([read_mask(out / "masks" / image_name(i)) for i in range(len(frames))])
    true = true_mattes_in_subject(truth, subject)[frames]
    assert np.abs(mattes - true).mean() < np.abs((mattes >= 0.5) - true).mean()


def test_pa_mpjpe_floor(captured, body):
    from pghm.capture.metrics import camera_joints, pa_mpjpe

    truth, out, _ = captured
    a, t = Subject.open(out).arrays, truth.arrays
    frames = np.asarray(a.frame_index)
    true = camera_joints(body, t.shape, t.rotations_true[frames], t.translation_true[frames], t.world_to_camera[frames])
    fitted = camera_joints(body, a.shape, a.rotations, a.translation, a.world_to_camera)
    assert 1000 * pa_mpjpe(fitted, true) <= PA_MPJPE_FLOOR_MM
