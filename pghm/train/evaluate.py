"""``pghm eval``: image quality of an avatar on a subject's held-out frames.

PSNR, SSIM (and LPIPS when its weights are on this machine) over whole images, of the dynamic
render I_d against the ground truth, with the poses and cameras the subject folder provides. On
white (the default, as the paper measures) the ground truth is the stored image; on another
background b it is the stored image moved through its alpha matte a onto b, I - (1 - a)(1 - b)
(:mod:`pghm.train.background`; m I + (1 - m) b for a binary mask). Whatever the background,
two silhouette measures:

    IoU   |{A > 0.5} & {m}| / |{A > 0.5} | {m}|, A the render's accumulated alpha;
    halo  the number of pixels outside the mask whose render on black has a mean RGB above
          HALO_LEVEL: a fringe that white hides and a dark background shows.

Writes a JSON report and a PNG strip (ground truth | render | error heat map) of a few frames.
"""

from __future__ import annotations

import io
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from torch import Tensor

from pghm.body import load_body
from pghm.errors import PghmError
from pghm.io.atomic import all_or_none
from pghm.io.avatar import Avatar, load_avatar, recorded_path
from pghm.train import pose_refine
from pghm.train.background import WHITE
from pghm.train.data import TrainingData
from pghm.train.fit import POSE_LR, FitConfig
from pghm.train.frames import on_background, render_images
from pghm.train.losses import psnr, ssim
from pghm.train.lpips import load_lpips, lpips_status
from pghm.train.pose_track import track_corrections

ERROR_SCALE = 0.25
"""Mean absolute RGB error shown at full intensity in the heat map."""
STRIP_FRAMES = 6
HALO_LEVEL = 0.25
"""Mean RGB above which a pixel outside the mask counts as halo, rendered on black."""
COVERED = 0.5
"""Accumulated alpha above which a render's pixel counts as inside its silhouette."""


@dataclass
class EvalResult:
    """Per-image metrics and their means."""

    psnr: list[float]
    ssim: list[float]
    lpips: list[float] | None
    images: list[int]
    iou: list[float] = field(default_factory=list)
    halo: list[int] = field(default_factory=list)
    background: tuple[float, float, float] = WHITE

    def summary(self) -> dict:
        def mean(values):
            finite = [v for v in values if math.isfinite(v)]
            return float(np.mean(finite)) if len(finite) == len(values) else math.inf

        out = {
            "images": len(self.images),
            "background": list(self.background),
            "psnr": mean(self.psnr),
            "ssim": float(np.mean(self.ssim)),
            "iou": float(np.mean(self.iou)),
            "halo_pixels": float(np.mean(self.halo)),
        }
        if self.lpips is not None:
            out["lpips"] = float(np.mean(self.lpips))
        return out


def silhouette_iou(alpha: Tensor, mask: Tensor) -> float:
    """IoU of the covered pixels {alpha > COVERED} of a render's alpha (H, W) and a mask (H, W)
    in {0, 1}; 1 when both are empty."""
    covered, inside = alpha > COVERED, mask > 0.5
    union = int((covered | inside).sum())
    return int((covered & inside).sum()) / union if union else 1.0


def halo_pixels(rgb_on_black: Tensor, mask: Tensor) -> int:
    """The pixels outside the mask (H, W) whose render on black (3, H, W) has a mean RGB above HALO_LEVEL."""
    return int(((rgb_on_black.mean(0) > HALO_LEVEL) & (mask <= 0.5)).sum())


def heat_map(error: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 'inferno' colours of a (H, W) error in [0, ERROR_SCALE]."""
    from matplotlib import colormaps

    return (colormaps["inferno"](np.clip(error / ERROR_SCALE, 0, 1))[..., :3] * 255).astype(np.uint8)


def evaluate(
    avatar: str | Path | Avatar,
    subject_dir: str | Path,
    report: str | Path | None = None,
    strip: str | Path | None = None,
    split: str = "test",
    body_model_path: str | None = None,
    true_poses: bool = False,
    images: list[int] | None = None,
    background: tuple[float, float, float] = WHITE,
    refine_poses: int = 0,
    fit_poses: bool = False,
    device: torch.device | str = "cpu",
) -> EvalResult:
    """Metrics of ``avatar`` on the ``split`` images of the subject; optional JSON and PNG outputs.

    Args:
        true_poses: render with a synthetic subject's exact poses rather than the stored
            estimates (measures appearance apart from pose error).
        images: evaluate only these image indices of the split (None: all of them).
        background: (r, g, b) in [0, 1] behind the render and the target (white: the paper's).
        refine_poses: steps of test-time pose refinement (:mod:`pghm.train.pose_refine`) before
            rendering: the held-out frames' poses fitted to their images, the avatar frozen; 0: off.
        fit_poses: render with the avatar's pose track (:mod:`pghm.train.pose_track`): the
            corrections its fit learned on the training frames, and on the held-out frames those
            the fit aligned to their images once the avatar was finished (a capture's; the report
            counts them), else the training frames' interpolated.
        device: where the avatar renders (and its poses are refined); metrics are computed on the CPU.
    """
    background = tuple(float(c) for c in background)
    avatar = (avatar if isinstance(avatar, Avatar) else load_avatar(avatar)).to(device)
    if avatar.kind != "avatar":
        raise PghmError("eval needs a personalised avatar (from pghm fit), not a prior")
    if fit_poses and (refine_poses > 0 or true_poses):
        raise PghmError("the fit's pose track is one choice of poses; give it without --refine-poses or --true-poses")
    if fit_poses and avatar.pose_track is None:
        raise PghmError(
            "the avatar holds no pose track (fitted with --no-pose-refinement or --pose-smoothing, or by an older pghm)"
        )
    data = TrainingData(subject_dir, split=split, true_poses=true_poses)
    data.check_body(avatar.body_name, "the avatar")
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
    corrections, refine_seconds, poses = None, 0.0, "exact (synthetic)" if true_poses else "as stored"
    if fit_poses:
        corrections, counts = track_corrections(avatar.pose_track, data, load_body(data.body_name, body_model_path))
        corrections = corrections.to(avatar.device)
        poses = (
            "the fit's pose track ({trained} frames trained on, {aligned} held out and aligned to their images "
            "after the fit, {interpolated} interpolated, {stored} as stored)"
        )
        poses = poses.format(**counts)
    if refine_poses > 0:
        started = time.perf_counter()
        loss = FitConfig().stage2.loss  # the fit's own objective, so a frozen avatar sees what it was fitted with
        corrections = pose_refine.refine_poses(
            avatar, data, refine_poses, loss, POSE_LR, images=indices, body_model_path=body_model_path
        )
        refine_seconds = time.perf_counter() - started
    strip_at = set(indices[:: max(1, len(indices) // STRIP_FRAMES)][:STRIP_FRAMES])
    result = EvalResult([], [], [] if lpips is not None else None, [], background=background)
    rows = []
    for sample, rgb_on_black, alpha in render_images(avatar, data, indices, body_model_path, corrections):
        index = sample.image_index
        target, image = on_background(sample, rgb_on_black, alpha, background)
        result.images.append(index)
        result.iou.append(silhouette_iou(alpha, sample.mask[0]))
        result.halo.append(halo_pixels(rgb_on_black.clamp(0, 1), sample.mask[0]))
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
            "subject": recorded_path(subject_dir),
            "split": split,
            "poses": poses,
            "pose_refinement": {"steps": refine_poses, "seconds": round(refine_seconds, 1)},
            "mean": result.summary(),
            "threads": torch.get_num_threads(),  # the last bits of every figure depend on it
            "lpips": lpips_status(directories=False),
            "halo": f"pixels outside the mask with mean RGB above {HALO_LEVEL} rendered on black",
            "per_image": [
                {
                    "image": i,
                    "psnr": p,
                    "ssim": s,
                    "iou": u,
                    "halo_pixels": h,
                    **({"lpips": lp} if lp is not None else {}),
                }
                for i, p, s, u, h, lp in zip(
                    result.images,
                    result.psnr,
                    result.ssim,
                    result.iou,
                    result.halo,
                    result.lpips or [None] * len(result.images),
                )
            ],
        }
    with all_or_none() as outputs:  # the report and the strip, both or neither
        if report is not None:
            outputs.write_bytes(report, json.dumps(payload, indent=2, allow_nan=True).encode())
        if strip is not None and rows:
            buffer = io.BytesIO()
            Image.fromarray(np.concatenate(rows, axis=0)).save(buffer, format="PNG")
            outputs.write_bytes(strip, buffer.getvalue())
    return result
