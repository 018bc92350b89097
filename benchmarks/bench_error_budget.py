"""Where a captured subject's held-out error comes from: ``pghm eval``'s squared error split by region.

For an avatar and its subject, the held-out frames (``--split train``: the training frames, which
tell what the avatar cannot draw from what it fails to generalise) are rendered as ``pghm eval
--refine-poses N`` renders them (the same refinement, on white against the stored image;
``--fit-poses``: with the avatar's pose track, as ``pghm eval --fit-poses``) and each pixel's
squared error (mean over RGB) is given to one region, in this order of precedence:

    ball      a held object: the strongly orange pixels of the truth inside its mask (a basketball),
              grown to the disc around them, within ``BAND`` px of the mask (``--ball``);
    band      the pixels within k px of the truth mask's boundary, on either side;
    interior  the rest of the mask;
    exterior  the rest of the image.

Per region: its share of the error and the PSNR were its error gone (the render equal to the
truth there; the mean of the frames' PSNRs, as ``pghm eval`` averages).

For a synthetic video made by ``bench_real.turning_video`` (``--turning-seed``), the generator's
frames are rendered again: their exact alpha and the person on white (the ideal truth). Then
also the captured masks against the true ones (IoU, mean boundary distance in px), and each
region's error split three ways: the render against the stored truth (what eval counts), the
render against the ideal truth (the avatar's own error), and the stored truth against the ideal
truth (the capture's: its mask and the video's compression).

Then what the outline costs, against the stored matte a (the truth's coverage):

    profile   per signed distance d to the matte's outline (px, rounded; negative inside): the
              pixels, the render's mean alpha and the matte's, and the share of the error;
    coverage  the PSNR of the avatar's own colours c = C / A composited through the matte
              (c a + 1 - a) and of the stored colours through the avatar's alpha: how much of
              the error is where the avatar covers, and how much what colour it has there;
    height    the share of the error in each tenth of the person's height (head to feet).

    python benchmarks/bench_error_budget.py AVATAR SUBJECT [--split train] [--ball] [--turning-seed 0]
                                           [--steps 30 | --fit-poses] [--band 2 4] [--results NAME]
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np
import torch
from common import print_table, setup_threads, write_json

from pghm.body import load_body
from pghm.capture.matte import outline_distance
from pghm.io.avatar import Avatar, load_avatar
from pghm.train import pose_refine
from pghm.train.background import WHITE
from pghm.train.data import TrainingData
from pghm.train.frames import on_background, render_images
from pghm.train.fit import POSE_LR, FitConfig
from pghm.train.pose_track import track_corrections

BALL_HUE = (3.0, 22.0)
"""Hue range (degrees) of a basketball's orange-brown."""
BALL_SATURATION = 0.5
"""Saturation above which an orange pixel is the ball's (skin and the shirt stay below it)."""
BALL_MIN_PIXELS = 200
"""Fewest orange pixels that make a ball (fewer: a glove's or a hand's fleck)."""
REGIONS = ("ball", "band", "interior", "exterior")
PROFILE_PX = 6
"""The outline profile's reach on either side (px)."""
COVERED = 0.05
"""Matte alpha above which a stored pixel's own colour is known (C / a)."""
HEIGHT_BINS = 10
"""The height table's bins: tenths of the person's height in the image."""
SWAPS = ("as rendered", "avatar colours, matte's coverage", "stored colours, avatar's coverage")
"""The composites :func:`coverage_swaps` scores."""


@dataclass(frozen=True)
class ScoredFrame:
    """One frame as eval renders it, (H, W[, 3]) float64 arrays in [0, 1].

    Attributes:
        index: the image's index in the subject.
        truth: the stored image (the person on white through the matte).
        render: the avatar on white.
        rgb: the avatar on black (premultiplied colour C).
        alpha: the avatar's coverage A.
        matte: the stored matte a.
    """

    index: int
    truth: np.ndarray
    render: np.ndarray
    rgb: np.ndarray
    alpha: np.ndarray
    matte: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        return self.matte > 0.5

    @cached_property
    def error(self) -> np.ndarray:
        """(H, W) squared error, mean over RGB (what eval averages)."""
        return ((self.render - self.truth) ** 2).mean(-1)


def ball_disc(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: the disc around the largest strongly orange blob of ``image`` (H, W, 3) uint8 inside ``mask``."""
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV_FULL).astype(np.float32)
    hue, saturation = hsv[..., 0] * 360 / 256, hsv[..., 1] / 255
    orange = (hue >= BALL_HUE[0]) & (hue <= BALL_HUE[1]) & (saturation > BALL_SATURATION) & mask
    count, labels, stats, _ = cv2.connectedComponentsWithStats(orange.astype(np.uint8), connectivity=8)
    disc = np.zeros(mask.shape, dtype=np.uint8)
    if count < 2 or stats[1:, cv2.CC_STAT_AREA].max() < BALL_MIN_PIXELS:
        return disc.astype(bool)
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    points = np.argwhere(labels == largest)[:, ::-1].astype(np.float32)
    (x, y), radius = cv2.minEnclosingCircle(points)
    cv2.circle(disc, (round(x), round(y)), math.ceil(radius), 1, thickness=-1)
    return disc.astype(bool)


def region_maps(mask: np.ndarray, band: float, ball: np.ndarray | None) -> dict[str, np.ndarray]:
    """Region name -> (H, W) bool, disjoint and covering the image (module doc)."""
    near = outline_distance(mask) <= band
    held = np.zeros_like(mask) if ball is None else ball & (mask | near)
    edge = near & ~held
    return {"ball": held, "band": edge, "interior": mask & ~edge & ~held, "exterior": ~mask & ~edge & ~held}


def psnr_of(mse: float) -> float:
    return -10 * math.log10(mse) if mse > 0 else math.inf


def budget(errors: list[np.ndarray], regions: list[dict[str, np.ndarray]]) -> list[dict]:
    """Per region: its pixel share, its share of the summed squared error, its RMS and the mean PSNR
    of the frames with its error removed; errors are (H, W) per frame."""
    total = sum(float(e.sum()) for e in errors)
    everything = {"pixels %": 100.0, "error %": 100.0, "RMS": math.sqrt(total / sum(e.size for e in errors))}
    rows = [{"region": "all", **everything, "PSNR without": float(np.mean([psnr_of(e.mean()) for e in errors]))}]
    for name in REGIONS:
        pixels = sum(int(r[name].sum()) for r in regions)
        area = sum(r[name].size for r in regions)
        error = sum(float(e[r[name]].sum()) for e, r in zip(errors, regions))
        without = np.mean([psnr_of(float(e[~r[name]].sum()) / e.size) for e, r in zip(errors, regions)])
        rows.append(
            {
                "region": name,
                "pixels %": 100 * pixels / area,
                "error %": 100 * error / total if total else 0.0,
                "RMS": math.sqrt(error / pixels) if pixels else 0.0,
                "PSNR without": float(without),
            }
        )
    return rows


def scored_frames(
    avatar: Avatar, subject: Path, steps: int, fit_poses: bool = False, split: str = "test"
) -> list[ScoredFrame]:
    """The ``split``'s frames rendered on white as ``pghm eval --split split --refine-poses steps``
    renders them, or with ``fit_poses`` as ``pghm eval --fit-poses`` does."""
    data = TrainingData(subject, split=split)
    indices = [int(i) for i in data.images[0]]
    corrections = None
    if fit_poses:
        corrections, _ = track_corrections(avatar.pose_track, data, load_body(avatar.body_name))
    elif steps > 0:
        loss = FitConfig().stage2.loss
        corrections = pose_refine.refine_poses(avatar, data, steps, loss, POSE_LR, images=indices)
    frames = []
    for sample, rgb_on_black, alpha in render_images(avatar, data, indices, corrections=corrections):
        target, image = on_background(sample, rgb_on_black, alpha, WHITE)
        frames.append(
            ScoredFrame(
                index=sample.image_index,
                truth=target.permute(1, 2, 0).numpy().astype(np.float64),
                render=image.permute(1, 2, 0).numpy().astype(np.float64),
                rgb=rgb_on_black.permute(1, 2, 0).numpy().astype(np.float64),
                alpha=alpha.reshape(image.shape[-2:]).numpy().astype(np.float64),
                matte=sample.mask[0].numpy().astype(np.float64),
            )
        )
    return frames


def outline_profile(frames: list[ScoredFrame], reach: int = PROFILE_PX) -> list[dict]:
    """Per signed distance d in [-reach, reach] to the matte's outline (rounded px, negative inside;
    0 never occurs): pixels, the render's and the matte's mean alpha, and the share of the error."""
    bins = 2 * reach + 1
    sums = np.zeros((4, bins))  # pixels, render alpha, matte alpha, error
    for f in frames:
        distance = np.rint(np.where(f.mask, -outline_distance(f.mask), outline_distance(f.mask))).astype(int)
        near = np.abs(distance) <= reach
        index = distance[near] + reach
        for row, weights in zip(sums, (None, f.alpha[near], f.matte[near], f.error[near])):
            row += np.bincount(index, weights, minlength=bins)
    total = sum(float(f.error.sum()) for f in frames)
    return [
        {
            "distance px": d,
            "pixels": int(n),
            "render alpha": a / n if n else math.nan,
            "matte alpha": m / n if n else math.nan,
            "error %": 100 * e / total if total else 0.0,
        }
        for d, (n, a, m, e) in zip(range(-reach, reach + 1), sums.T)
        if d
    ]


def coverage_swaps(frames: list[ScoredFrame]) -> dict[str, float]:
    """Mean PSNR of the render as it is, of the avatar's colours through the matte, and of the stored
    colours through the avatar's alpha (where the matte covers less than :data:`COVERED`, or the
    avatar covers nothing, the other side's colour stands in)."""
    psnr: dict[str, list[float]] = {name: [] for name in SWAPS}
    for f in frames:
        a, alpha = f.matte[..., None], f.alpha[..., None]
        stored = (f.truth - (1 - a)) / np.maximum(a, COVERED)
        own = np.where(alpha > 0, f.rgb / np.where(alpha > 0, alpha, 1.0), stored)
        stored = np.where(a > COVERED, stored, own)
        composites = (f.render, own * a + 1 - a, stored * alpha + 1 - alpha)
        for name, image in zip(SWAPS, composites):
            psnr[name].append(psnr_of(float(((np.clip(image, 0, 1) - f.truth) ** 2).mean())))
    return {name: float(np.mean(values)) for name, values in psnr.items()}


def height_shares(frames: list[ScoredFrame], bins: int = HEIGHT_BINS) -> list[float]:
    """% of the error in each of ``bins`` rows of the person's height in the image (from the matte),
    top to bottom; rows above and below the person count to the first and last."""
    shares = np.zeros(bins)
    for f in frames:
        rows = np.flatnonzero(f.mask.any(1))
        if not len(rows):
            continue
        top, bottom = rows[0], rows[-1] + 1
        band = np.clip((np.arange(f.mask.shape[0]) - top) * bins // (bottom - top), 0, bins - 1)
        np.add.at(shares, band, f.error.sum(1))
    return (100 * shares / shares.sum()).tolist() if shares.sum() else shares.tolist()


def true_views(subject: Path, indices: list[int], seed: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Image index -> (ideal truth (H, W, 3) float on white, true alpha (H, W) float) of the turning
    video ``bench_real.turning_video(..., seed)`` that ``subject`` was captured from, cut and scaled
    as the capture cut its frames (meta.json's crop; every frame kept)."""
    from PIL import Image

    from pghm.body import load_body
    from pghm.synth.generate import plan_subject, release_worker_gl, render_views
    from pghm.synth.video import SUBJECT_INDEX, walk_config

    meta = json.loads((subject / "meta.json").read_text())
    crop, counts = meta["crop"], meta["counts"]
    if counts["dropped"] or meta["options"]["every"] != 1:
        raise SystemExit(f"{subject}: frames were dropped or skipped; image i is not video frame i")
    config = walk_config(counts["frames_read"], width=crop["source_width"], height=crop["source_height"], motion="turn")
    plan = plan_subject(config, load_body("anny"), seed, SUBJECT_INDEX)
    size = Image.open(subject / "images" / f"{indices[0]:06d}.png").size
    box = (crop["x"], crop["y"], crop["x"] + crop["width"], crop["y"] + crop["height"])

    def cut(pixels: np.ndarray) -> np.ndarray:
        resized = Image.fromarray(pixels).resize(size, Image.Resampling.LANCZOS, box=box)
        return np.asarray(resized).astype(np.float64) / 255

    views = {}
    try:
        for index, view in render_views(config, plan, indices):
            views[index] = (cut(view.rgb), cut(view.coverage))
    finally:
        release_worker_gl()
    return views


def boundary_px(captured: np.ndarray, true: np.ndarray) -> float:
    """Mean symmetric distance (px) between the boundary pixels of two (H, W) bool masks."""
    edges = [m & (outline_distance(m) <= 1) for m in (captured, true)]
    to_true, to_captured = outline_distance(true), outline_distance(captured)
    return float(np.concatenate([to_true[edges[0]], to_captured[edges[1]]]).mean())


def mask_agreement(captured: list[np.ndarray], true: list[np.ndarray]) -> dict:
    iou = [float((c & t).sum() / max(1, (c | t).sum())) for c, t in zip(captured, true)]
    boundary = [boundary_px(c, t) for c, t in zip(captured, true)]
    return {"iou": float(np.mean(iou)), "boundary_px": float(np.mean(boundary))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("avatar", type=Path)
    parser.add_argument("subject", type=Path)
    parser.add_argument("--steps", type=int, default=30, help="test-time pose refinement steps (pghm eval's)")
    parser.add_argument("--fit-poses", action="store_true", help="the avatar's pose track instead of refinement")
    parser.add_argument("--split", default="test", help="the subject's split to score (default test)")
    parser.add_argument("--band", type=float, nargs="+", default=[2.0, 4.0], help="band half-widths (px)")
    parser.add_argument("--ball", action="store_true", help="count a held orange ball as its own region")
    parser.add_argument("--turning-seed", type=int, default=None, help="the subject is bench_real's turning video")
    parser.add_argument("--results", default=None, help="write benchmarks/results/<name>.json")
    args = parser.parse_args()
    setup_threads()
    torch.manual_seed(0)
    frames = scored_frames(load_avatar(args.avatar), args.subject, args.steps, args.fit_poses, args.split)
    truth = None
    if args.turning_seed is not None:
        truth = true_views(args.subject, [f.index for f in frames], args.turning_seed)
    poses = "fit" if args.fit_poses else f"refined {args.steps}"
    payload = {"avatar": args.avatar.name, "subject": args.subject.name, "split": args.split, "poses": poses}
    payload["bands"] = {}
    for band in args.band:
        balls = [ball_disc((f.truth * 255).round().astype(np.uint8), f.mask) if args.ball else None for f in frames]
        regions = [region_maps(f.mask, band, ball) for f, ball in zip(frames, balls)]
        tables = {"eval (render - stored truth)": [f.error for f in frames]}
        if truth is not None:
            tables["avatar (render - ideal truth)"] = [((f.render - truth[f.index][0]) ** 2).mean(-1) for f in frames]
            tables["capture (stored - ideal truth)"] = [((f.truth - truth[f.index][0]) ** 2).mean(-1) for f in frames]
        payload["bands"][band] = {}
        for name, errors in tables.items():
            print(f"\nband {band:g} px, {name}")
            rows = budget(errors, regions)
            print_table(rows)
            payload["bands"][band][name] = rows
    payload["profile"] = outline_profile(frames)
    print("\nby signed distance to the matte's outline (negative inside)")
    print_table(payload["profile"])
    payload["coverage"] = coverage_swaps(frames)
    print("\nPSNR with the coverage or the colours swapped for the stored ones")
    print_table([{"composite": name, "PSNR": value} for name, value in payload["coverage"].items()])
    payload["height %"] = height_shares(frames)
    print(f"\nerror % by tenth of the person's height, head to feet: {np.round(payload['height %'], 1).tolist()}")
    if truth is not None:
        true_masks = [truth[f.index][1] >= 0.5 for f in frames]
        payload["masks"] = mask_agreement([f.mask for f in frames], true_masks)
        print(f"\ncaptured masks against the true alpha >= 0.5: {payload['masks']}")
    if args.results:
        write_json(args.results, payload)


if __name__ == "__main__":
    main()
