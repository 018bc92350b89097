"""Body fit on synthetic observations made from a known body (round trip against the truth).

The truth: a random Anny shape doing a synthetic motion (pghm.synth.poses) before a
known camera. Its landmark points (through the measured correspondence) are projected with
pixel noise, its hip-centred camera-frame landmarks get metric noise (MediaPipe's world
landmarks), and its masks are rasterised from the projected mesh. The fit sees only these
observations (no pose, shape or, in one case, focal length) and must recover the joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch
from scipy.ndimage import binary_closing, binary_fill_holes

from pghm.body import BodyPose, load_body
from pghm.capture.bodyfit import HEIGHT_PHENOTYPE, fit_body, rest_height, shape_of_height
from pghm.capture.config import HEIGHT_RANGE_M, BodyFitConfig, CaptureConfig
from pghm.capture.frontend import Observations
from pghm.capture.landmarks import BODY_LANDMARKS, NUM_LANDMARKS, landmark_points
from pghm.capture.metrics import camera_joints, error_2d_percent, mpjpe, pa_mpjpe, project
from pghm.errors import PghmError
from pghm.synth.cameras import intrinsics, look_at
from pghm.synth.poses import place_on_path, synth_motion

FRAMES = 24
SIZE = 320
PIXEL_NOISE = 1.5
METRIC_NOISE = 0.02


@dataclass
class Truth:
    shape: np.ndarray
    rotations: np.ndarray
    translation: np.ndarray
    K: np.ndarray
    world_to_camera: np.ndarray
    height_px: np.ndarray


def rasterise(pixels: np.ndarray, size: int) -> np.ndarray:
    """(size, size) bool mask of the pixels (N, 2) hit by projected vertices, closed and filled."""
    mask = np.zeros((size, size), bool)
    cols, rows = np.floor(pixels).astype(int).T
    keep = (rows >= 0) & (rows < size) & (cols >= 0) & (cols < size)
    mask[rows[keep], cols[keep]] = True
    return binary_fill_holes(binary_closing(mask, iterations=2))


def synthetic(kind: str, seed: int) -> tuple[Observations, Truth]:
    rng = np.random.default_rng(seed)
    body = load_body("anny")
    shape = torch.as_tensor(rng.uniform(0.2, 0.8, len(body.shape_names)), dtype=torch.float32)
    rest = body.rest(shape)
    rotations, translation = synth_motion(kind, body, rest.joints, FRAMES, 30.0, rng)
    heading = np.full(FRAMES, rng.uniform(-0.6, 0.6))
    rotations, translation = place_on_path(rotations, translation, heading, np.zeros((FRAMES, 3)))
    pose = BodyPose(torch.as_tensor(rotations, dtype=torch.float32), torch.as_tensor(translation, dtype=torch.float32))
    vertices = body.posed_vertices(pose, rest)
    world_to_camera = look_at(np.array([0.3, 1.2, 3.6]), np.array([0.0, 0.9, 0.0]))
    K = intrinsics(380.0, SIZE, SIZE)  # noqa: N806
    cam = vertices.double().numpy() @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    pixels = project(cam, K)
    marks = landmark_points(torch.as_tensor(cam)).numpy()  # (F, L, 3) camera frame
    index = list(BODY_LANDMARKS)
    hips = marks[:, [index.index(23), index.index(24)]].mean(1, keepdims=True)
    landmarks_2d = np.zeros((FRAMES, NUM_LANDMARKS, 2), np.float32)
    landmarks_3d = np.zeros((FRAMES, NUM_LANDMARKS, 3), np.float32)
    confidence = np.zeros((FRAMES, NUM_LANDMARKS), np.float32)
    landmarks_2d[:, index] = project(marks, K) + rng.normal(0, PIXEL_NOISE, (FRAMES, len(index), 2))
    landmarks_3d[:, index] = marks - hips + rng.normal(0, METRIC_NOISE, (FRAMES, len(index), 3))
    confidence[:, index] = rng.uniform(0.6, 1.0, (FRAMES, len(index)))
    masks = np.stack([rasterise(p, SIZE) for p in pixels])
    observations = Observations(
        np.arange(FRAMES, dtype=np.int32),
        (SIZE, SIZE),
        K.astype(np.float32),
        landmarks_2d,
        confidence,
        landmarks_3d,
        masks,
    )
    height_px = np.ptp(pixels[..., 1], axis=1)
    return observations, Truth(shape.numpy(), rotations, translation, K, world_to_camera, height_px)


def joint_errors(fit, truth: Truth) -> tuple[float, float, float]:
    """MPJPE and PA-MPJPE (mm) of the canonical joints in camera coordinates, and 2D error (% height)."""
    body = load_body("anny")
    true = camera_joints(body, truth.shape, truth.rotations, truth.translation, truth.world_to_camera)
    pred = camera_joints(body, fit.shape, fit.rotations, fit.translation, fit.world_to_camera)
    error_2d = error_2d_percent(project(pred, fit.K), project(true, truth.K), truth.height_px)
    return 1000 * mpjpe(pred, true), 1000 * pa_mpjpe(pred, true), error_2d


@pytest.mark.parametrize("kind,seed,known_focal", [("walk", 1, True), ("dance", 2, False)])
def test_fit_recovers_synthetic_joints(kind: str, seed: int, known_focal: bool) -> None:
    observations, truth = synthetic(kind, seed)
    if not known_focal:
        observations.K = None
    fit = fit_body(observations, BodyFitConfig())
    body = load_body("anny")
    assert fit.rotations.shape == (FRAMES, body.num_bones, 3)
    assert fit.translation.shape == (FRAMES, 3)
    assert fit.world_to_camera.shape == (4, 4) and fit.K.shape == (3, 3)
    assert all(np.isfinite(a).all() for a in (fit.shape, fit.rotations, fit.translation, fit.world_to_camera, fit.K))
    assert ((fit.shape >= 0) & (fit.shape <= 1)).all()
    rotation = fit.world_to_camera[:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-5)
    if known_focal:
        np.testing.assert_allclose(fit.K, truth.K, rtol=1e-6)
    mpjpe_mm, pa_mpjpe_mm, error_2d = joint_errors(fit, truth)
    assert pa_mpjpe_mm < 50.0
    assert mpjpe_mm < 80.0
    assert error_2d < 2.0


def test_rest_bones_stay_at_rest() -> None:
    observations, _ = synthetic("walk", 3)
    fit = fit_body(observations, BodyFitConfig(steps=(5, 5, 5)))
    body = load_body("anny")
    moved = np.flatnonzero(np.abs(fit.rotations).sum((0, 2)) > 0)
    fitted = {0} | {body.joint_map[n] for n in ("left_elbow", "right_knee", "head")}
    assert fitted <= set(moved.tolist())
    at_rest = ("finger", "metacarpal", "toe", "eye")
    hands = [i for i, name in enumerate(body.bone_names) if name.startswith(at_rest)]
    assert hands and not set(hands) & set(moved.tolist())


def test_bad_observations_name_the_problem() -> None:
    observations, _ = synthetic("walk", 4)
    observations.landmarks_2d = observations.landmarks_2d[:, :20]
    with pytest.raises(PghmError, match="landmarks_2d"):
        fit_body(observations)
    with pytest.raises(PghmError, match="smplx"):
        fit_body(observations, BodyFitConfig(body="smplx"))
    observations, _ = synthetic("walk", 4)
    observations.K = None
    observations.frame_box = np.array([10.0, 0.0, 5.0, 100.0], np.float32)  # x1 < x0
    with pytest.raises(PghmError, match="frame_box"):
        fit_body(observations)


@pytest.mark.parametrize("step", [1, 3, 4])
def test_mask_map_is_read_where_its_pixels_are(step: int) -> None:
    """A map keeping every step-th pixel of a (H, W) image is read, at a full-size pixel centre
    (x + 1/2, y + 1/2) with x, y multiples of step, exactly at the map pixel holding that pixel;
    half-way between two kept pixels it reads their mean (bilinear)."""
    from pghm.capture.bodyfit import _map_grid

    height, width = 37, 53
    full = torch.arange(height * width, dtype=torch.float32).reshape(height, width)
    kept = full[::step, ::step]
    ys, xs = torch.meshgrid(torch.arange(kept.shape[0]), torch.arange(kept.shape[1]), indexing="ij")
    centres = torch.stack([xs * step + 0.5, ys * step + 0.5], -1).reshape(1, -1, 2).float()

    def read(pixels: torch.Tensor) -> torch.Tensor:
        grid = _map_grid(pixels, step, tuple(kept.shape))
        return torch.nn.functional.grid_sample(kept[None, None], grid[:, None], align_corners=False)[0, 0, 0]

    torch.testing.assert_close(read(centres), kept.reshape(-1), rtol=0, atol=1e-2)
    if step > 1:
        between = centres[:, :-1] + torch.tensor([step / 2, 0.0])
        inner = (xs < kept.shape[1] - 1).reshape(-1)[:-1]
        expected = 0.5 * (kept.reshape(-1)[:-1] + kept.reshape(-1)[1:])
        torch.testing.assert_close(read(between)[inner], expected[inner], rtol=0, atol=1e-2)


def test_height_range_is_the_body_models() -> None:
    """--height's bounds are the heights of Anny's average body at its height phenotype's ends."""
    body = load_body("anny")
    shape = body.default_shape()
    for value, expected in zip((0.0, 1.0), HEIGHT_RANGE_M, strict=True):
        shape[body.shape_names.index(HEIGHT_PHENOTYPE)] = value
        assert abs(rest_height(body, shape) - expected) < 0.01


def test_shape_of_height_changes_the_height_phenotype_only() -> None:
    body = load_body("anny")
    k = body.shape_names.index(HEIGHT_PHENOTYPE)
    for height in (1.5, 1.89):
        shape = shape_of_height(body, height)
        assert abs(rest_height(body, shape) - height) < 1e-3
        np.testing.assert_array_equal(np.delete(shape.numpy(), k), np.delete(body.default_shape().numpy(), k))
    with pytest.raises(PghmError, match="--height 2.5 m"):
        shape_of_height(body, 2.5)
    with pytest.raises(PghmError, match="--height must be 1.12 to 2.13 m"):
        CaptureConfig(height_m=0.9).validate()


def test_a_given_height_is_the_fitted_height() -> None:
    """Seed 3's body is 1.22 m, far from the average adult the fit assumes (1.63 m): told its height, the
    fit makes it that tall and recovers the joints (MPJPE 46 mm without it, measured: its size is
    what one camera does not tell)."""
    observations, truth = synthetic("walk", 3)
    body = load_body("anny")
    true_height = rest_height(body, torch.as_tensor(truth.shape))
    fit = fit_body(observations, BodyFitConfig(height_m=true_height))
    assert abs(rest_height(body, torch.as_tensor(fit.shape)) - true_height) < 0.005
    mpjpe_mm, pa_mpjpe_mm, _ = joint_errors(fit, truth)
    assert mpjpe_mm < 30.0 and pa_mpjpe_mm < 30.0
