"""``pghm eval``: image quality of an avatar on a subject's held-out frames.

PSNR, SSIM (and LPIPS when its weights are on this machine) over whole images on a white
background, as the paper measures, of the dynamic render I_d against the ground truth,
with the poses and cameras the subject folder provides. Writes a JSON report and a PNG
strip (ground truth | render | error heat map) of a few frames.
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from pghm.body.pose import BodyPose
from pghm.errors import PghmError
from pghm.io.atomic import atomic_write_bytes
from pghm.io.avatar import Avatar, avatar_geometry, load_avatar
from pghm.model.evaluator import CachedEvaluator
from pghm.splat import render
from pghm.train.data import TrainingData
from pghm.train.loop import BACKGROUND
from pghm.train.losses import psnr, ssim
from pghm.train.lpips import load_lpips, lpips_status

ERROR_SCALE = 0.25
"""Mean absolute RGB error shown at full intensity in the heat map."""
STRIP_FRAMES = 6


@dataclass
class EvalResult:
    """Per-image metrics and their means."""

    psnr: list[float]
    ssim: list[float]
    lpips: list[float] | None
    images: list[int]

    def summary(self) -> dict:
        def mean(values):
            finite = [v for v in values if math.isfinite(v)]
            return float(np.mean(finite)) if len(finite) == len(values) else math.inf

        out = {"images": len(self.images), "psnr": mean(self.psnr), "ssim": float(np.mean(self.ssim))}
        if self.lpips is not None:
            out["lpips"] = float(np.mean(self.lpips))
        return out


def heat_map(error: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 'inferno' colours of a (H, W) error in [0, ERROR_SCALE]."""
    from matplotlib import colormaps

    return (colormaps["inferno"](np.clip(error / ERROR_SCALE, 0, 1))[..., :3] * 255).astype(np.uint8)


def render_images(avatar: Avatar, data: TrainingData, indices: list[int], body_model_path: str | None = None):
    """Yield (index, target (3,H,W), render (3,H,W)) of the dynamic Gaussians, one image at a time."""
    evaluator = CachedEvaluator(avatar.model.eval(), avatar_geometry(avatar, body_model_path=body_model_path))
    identity = avatar.identity_map()
    for index in indices:
        sample = data.load(0, index)
        pose = BodyPose(sample.rotations[None], sample.translation[None])
        g = evaluator.evaluate(identity, pose, sample.camera.centre.float()).dynamic
        with torch.no_grad():
            image = render(
                g.means[0], g.scales[0], g.colors[0], g.opacities[0], sample.camera, background=BACKGROUND
            ).rgb
        yield index, sample.image, image.permute(2, 0, 1).clamp(0, 1)


def evaluate(
    avatar: str | Path | Avatar,
    subject_dir: str | Path,
    report: str | Path | None = None,
    strip: str | Path | None = None,
    split: str = "test",
    body_model_path: str | None = None,
    true_poses: bool = False,
    images: list[int] | None = None,
) -> EvalResult:
    """Metrics of ``avatar`` on the ``split`` images of the subject; optional JSON and PNG outputs.

    Args:
        true_poses: render with a synthetic subject's exact poses rather than the stored
            estimates (measures appearance apart from pose error).
        images: evaluate only these image indices of the split (None: all of them).
    """
    avatar = avatar if isinstance(avatar, Avatar) else load_avatar(avatar)
    if avatar.kind != "avatar":
        raise PghmError("eval needs a personalised avatar (from pghm fit), not a prior")
    data = TrainingData(subject_dir, split=split, true_poses=true_poses)
    if data.num_identities != 1:
        names = ", ".join(subject.directory.name for subject in data.subjects[:5])
        more = ", ..." if data.num_identities > 5 else ""
        raise PghmError(
            f"{subject_dir}: a data set of {data.num_identities} subjects ({names}{more}); "
            "eval takes one subject folder"
        )
    lpips = load_lpips()
    indices = [int(i) for i in data.images[0]]
    if images is not None:
        outside = sorted(set(images) - set(indices))
        if outside:
            raise PghmError(f"images {outside[:5]} are not in the subject's '{split}' split")
        indices = [int(i) for i in images]
    strip_at = set(indices[:: max(1, len(indices) // STRIP_FRAMES)][:STRIP_FRAMES])
    result = EvalResult([], [], [] if lpips is not None else None, [])
    rows = []
    for index, target, image in render_images(avatar, data, indices, body_model_path):
        result.images.append(index)
        result.psnr.append(float(psnr(image[None], target[None])))
        result.ssim.append(float(ssim(image[None], target[None])))
        if lpips is not None:
            result.lpips.append(float(lpips(image[None], target[None])))
        if index in strip_at:
            gt = (target.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
            out = (image.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
            error = heat_map((image - target).abs().mean(0).numpy())
            rows.append(np.concatenate([gt, out, error], axis=1))
    if report is not None:
        payload = {
            "avatar_metadata": avatar.metadata,
            "subject": str(Path(subject_dir).resolve()),
            "split": split,
            "poses": "exact (synthetic)" if true_poses else "as stored",
            "mean": result.summary(),
            "lpips": lpips_status(),
            "per_image": [
                {"image": i, "psnr": p, "ssim": s, **({"lpips": lp} if lp is not None else {})}
                for i, p, s, lp in zip(
                    result.images, result.psnr, result.ssim, result.lpips or [None] * len(result.images)
                )
            ],
        }
        atomic_write_bytes(report, json.dumps(payload, indent=2, allow_nan=True).encode())
    if strip is not None and rows:
        buffer = io.BytesIO()
        Image.fromarray(np.concatenate(rows, axis=0)).save(buffer, format="PNG")
        atomic_write_bytes(strip, buffer.getvalue())
    return result
