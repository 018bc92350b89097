"""Where a captured subject's held-out error comes from: ``pghm eval``'s squared error split by region.

For an avatar and its subject, the held-out frames are rendered as ``pghm eval --refine-poses N``
renders them (the same refinement, on white against the stored image) and each pixel's squared
error (mean over RGB) is given to one region, in this order of precedence:

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

    python benchmarks/bench_error_budget.py AVATAR SUBJECT [--ball] [--turning-seed 0] [--steps 30]
                                           [--band 2 4] [--results NAME]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import cv2
import numpy as np
import torch
from common import print_table, setup_threads, write_json

from pghm.capture.matte import outline_distance
from pghm.io.avatar import load_avatar
from pghm.train import pose_refine
from pghm.train.background import WHITE
from pghm.train.data import TrainingData
from pghm.train.evaluate import on_background, render_images
from pghm.train.fit import POSE_LR, FitConfig

BALL_HUE = (3.0, 22.0)
"""Hue range (degrees) of a basketball's orange-brown."""
BALL_SATURATION = 0.5
"""Saturation above which an orange pixel is the ball's (skin and the shirt stay below it)."""
BALL_MIN_PIXELS = 200
"""Fewest orange pixels that make a ball (fewer: a glove's or a hand's fleck)."""
REGIONS = ("ball", "band", "interior", "exterior")


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


def refined_frames(avatar_path: Path, subject: Path, steps: int):
    """[(image index, truth (H, W, 3) float, render (H, W, 3) float, mask (H, W) bool)] of the test
    split, rendered as ``pghm eval --refine-poses steps`` renders them on white."""
    avatar = load_avatar(avatar_path)
    data = TrainingData(subject, split="test")
    indices = [int(i) for i in data.images[0]]
    corrections = None
    if steps > 0:
        loss = FitConfig().stage2.loss
        corrections = pose_refine.refine_poses(avatar, data, steps, loss, POSE_LR, images=indices)
    frames = []
    for sample, rgb_on_black, alpha in render_images(avatar, data, indices, corrections=corrections):
        target, image = on_background(sample, rgb_on_black, alpha, WHITE)
        frames.append(
            (
                sample.image_index,
                target.permute(1, 2, 0).numpy().astype(np.float64),
                image.permute(1, 2, 0).numpy().astype(np.float64),
                sample.mask[0].numpy() > 0.5,
            )
        )
    return frames


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
    parser.add_argument("--band", type=float, nargs="+", default=[2.0, 4.0], help="band half-widths (px)")
    parser.add_argument("--ball", action="store_true", help="count a held orange ball as its own region")
    parser.add_argument("--turning-seed", type=int, default=None, help="the subject is bench_real's turning video")
    parser.add_argument("--results", default=None, help="write benchmarks/results/<name>.json")
    args = parser.parse_args()
    setup_threads()
    torch.manual_seed(0)
    frames = refined_frames(args.avatar, args.subject, args.steps)
    truth = None
    if args.turning_seed is not None:
        truth = true_views(args.subject, [f[0] for f in frames], args.turning_seed)
    payload = {"avatar": args.avatar.name, "subject": args.subject.name, "steps": args.steps, "bands": {}}
    for band in args.band:
        regions = [
            region_maps(mask, band, ball_disc((t * 255).round().astype(np.uint8), mask) if args.ball else None)
            for _, t, _, mask in frames
        ]
        tables = {"eval (render - stored truth)": [((r - t) ** 2).mean(-1) for _, t, r, _ in frames]}
        if truth is not None:
            tables["avatar (render - ideal truth)"] = [((r - truth[i][0]) ** 2).mean(-1) for i, _, r, _ in frames]
            tables["capture (stored - ideal truth)"] = [((t - truth[i][0]) ** 2).mean(-1) for i, t, _, _ in frames]
        payload["bands"][band] = {}
        for name, errors in tables.items():
            print(f"\nband {band:g} px, {name}")
            rows = budget(errors, regions)
            print_table(rows)
            payload["bands"][band][name] = rows
    if truth is not None:
        true_masks = [truth[i][1] >= 0.5 for i, *_ in frames]
        payload["masks"] = mask_agreement([m for *_, m in frames], true_masks)
        print(f"\ncaptured masks against the true alpha >= 0.5: {payload['masks']}")
    if args.results:
        write_json(args.results, payload)


if __name__ == "__main__":
    main()
