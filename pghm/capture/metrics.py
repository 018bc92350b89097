"""Accuracy of a body fit against a known truth: MPJPE, PA-MPJPE and 2D error.

The joints are the canonical joints (:data:`pghm.body.CANONICAL_JOINTS`) the backend maps,
in camera coordinates (OpenCV axes, metres). MPJPE is root-relative (both skeletons moved
so their pelvis is at the origin); PA-MPJPE first aligns each predicted frame to the
truth with the best similarity transform (Procrustes: scale, rotation, translation), as
the 3DPW/Human3.6M protocols do. The 2D error is in pixels, divided by the person's height
in pixels.
"""

from __future__ import annotations

import numpy as np
import torch

from pghm.body import BodyModel, BodyPose
from pghm.body.model import CANONICAL_JOINTS


def mapped_joints(body: BodyModel) -> tuple[list[str], list[int]]:
    """The canonical joints ``body`` maps, and their bone indices."""
    names = [name for name in CANONICAL_JOINTS if name in body.joint_map]
    return names, [body.joint_map[name] for name in names]


def camera_joints(
    body: BodyModel,
    shape: np.ndarray,
    rotations: np.ndarray,
    translation: np.ndarray,
    world_to_camera: np.ndarray,
) -> np.ndarray:
    """Posed canonical joints in camera coordinates.

    Args:
        shape: (S,) body shape.
        rotations: (F, J, 3) axis-angle; translation: (F, 3).
        world_to_camera: (4, 4) or (F, 4, 4).

    Returns:
        joints: (F, C, 3) metres, C = the mapped canonical joints (:func:`mapped_joints` order).
    """
    rest = body.rest(torch.as_tensor(shape, dtype=torch.float32))
    pose = BodyPose(torch.as_tensor(rotations, dtype=torch.float64), torch.as_tensor(translation, dtype=torch.float64))
    transforms = body.bone_transforms(pose, rest.joints.double())
    _, bones = mapped_joints(body)
    heads = rest.joints.double()[bones]
    world = ((transforms[:, bones, :3, :3] @ heads[..., None])[..., 0] + transforms[:, bones, :3, 3]).numpy()
    E = np.broadcast_to(np.asarray(world_to_camera, np.float64), (len(world), 4, 4))  # noqa: N806
    return np.einsum("fij,fcj->fci", E[:, :3, :3], world) + E[:, None, :3, 3]


def project(points: np.ndarray, K: np.ndarray) -> np.ndarray:  # noqa: N803
    """(F, C, 2) pixels of camera-frame points (F, C, 3) through (3, 3) or (F, 3, 3) intrinsics."""
    K = np.broadcast_to(np.asarray(K, np.float64), (len(points), 3, 3))  # noqa: N806
    uv = points[..., :2] / points[..., 2:]
    return uv * K[:, None, [0, 1], [0, 1]] + K[:, None, :2, 2]


def mpjpe(pred: np.ndarray, true: np.ndarray, root: int = 0) -> float:
    """Mean root-relative joint error (same units as the input) of (F, C, 3) joints; ``root``: the pelvis column."""
    pred_rel = pred - pred[:, root : root + 1]
    true_rel = true - true[:, root : root + 1]
    return float(np.linalg.norm(pred_rel - true_rel, axis=-1).mean())


def procrustes_align(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """``pred`` (F, C, 3) moved per frame by the similarity s R x + t closest to ``true`` (least squares).

    Umeyama: with centred X (pred), Y (true) and U S V^T = svd(X^T Y), R = V D U^T where
    D = diag(1, 1, det(V U^T)) excludes reflections, s = tr(S D) / |X|^2.
    """
    mu_p, mu_t = pred.mean(1, keepdims=True), true.mean(1, keepdims=True)
    x, y = pred - mu_p, true - mu_t
    u, sigma, vt = np.linalg.svd(np.einsum("fci,fcj->fij", x, y))
    d = np.ones_like(sigma)
    d[:, -1] = np.sign(np.linalg.det(np.einsum("fij,fjk->fik", u, vt)))
    rotation = np.einsum("fji,fj,fkj->fik", vt, d, u)  # R = V D U^T
    scale = (sigma * d).sum(-1) / (x**2).sum((1, 2))
    return scale[:, None, None] * np.einsum("fij,fcj->fci", rotation, x) + mu_t


def pa_mpjpe(pred: np.ndarray, true: np.ndarray) -> float:
    """Mean joint error of (F, C, 3) joints after per-frame Procrustes alignment."""
    return float(np.linalg.norm(procrustes_align(pred, true) - true, axis=-1).mean())


def error_2d_percent(pred_px: np.ndarray, true_px: np.ndarray, height_px: np.ndarray | float) -> float:
    """Mean 2D joint error of (F, C, 2) pixels as a percentage of the person's height, (F,) or scalar pixels."""
    height = np.broadcast_to(np.asarray(height_px, np.float64), (len(pred_px),))
    return float((100.0 * np.linalg.norm(pred_px - true_px, axis=-1) / height[:, None]).mean())
