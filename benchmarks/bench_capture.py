"""``pghm capture`` against the synthetic generator's truth (docs/capture.md, "How well it works").

Synthetic monocular walks (:mod:`pghm.synth.video`) are encoded as H.264 videos with
the person over two kinds of background, captured with ``pghm capture`` (defaults: the
focal length is estimated), and the subjects compared with the truth, per seed x background:

a. mask IoU against the true masks (mean over the video's frames; a dropped frame counts
   as IoU 0): >= 0.95 plain, >= 0.90 cluttered;
b. root-relative MPJPE and PA-MPJPE (per-frame similarity Procrustes) of the canonical
   joints (Anny's 20 of the 22), each body in its own camera's coordinates: <= 80 mm and <= 50 mm;
c. 2D error of the canonical joints projected by each camera, in source-video pixels, as
   % of the person's height in that frame (the true mask's extent): <= 2 %;
d. with ``--fit``: ``pghm fit`` (defaults, assets/prior.pt) on the captured subject and on
   the same subject with the true poses and cameras (the capture's images, masks, crop and
   split), each evaluated on the same test images: the captured one within 1.5 dB PSNR; again
   with the poses the captured fit learned for the video (``pghm eval --fit-poses``; the
   reference keeps its true poses); and
   with each test frame's pose first refined against its image (``pghm eval
   --refine-poses``, both sides). A third fit, on the true masks as well (the images
   composited through them), gives the stricter gap that includes the masks' error (a);
e. speed and memory of the pipeline on a 300-frame 512-px video (a child process running
   the front end and the body fit, timed apart; its peak resident memory): <= 120 s, <= 2 GB.

Backgrounds: "plain" is a gentle vertical gradient between two muted colours (a wall and
a floor); "cluttered" is a photograph without people or animals, shipped inside the
scikit-image wheel (no download): a garage with a motorcycle, a rocket on its launch pad,
a cup of coffee on a wooden table (one per seed).

    python benchmarks/bench_capture.py [--seeds 0 1 2] [--frames 100] [--fit [plain_0 ...]] [--keep DIR]
                                       [--backgrounds plain cluttered] [--results bench_capture]

Prints the table with each background's mean over the tuned seeds, and each target's verdict on
those means, on every tuned video and on every held-out video (seed 3); writes
benchmarks/results/bench_capture.json and docs/capture_bench*.png (other names with --results,
e.g. for a --fit run made apart from the table).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from common import BYTES_PER_GB, DOCS, KB, RESULTS, ROOT, load_average, print_table, timed_child, write_json
from PIL import Image

from pghm.capture.crop import Region, crop_intrinsics, from_region
from pghm.subject import Subject, check, read_mask
from pghm.synth.poses import MOTION_KINDS
from pghm.synth.video import WalkTruth, graded_background, render_walk_video, walk_config

if TYPE_CHECKING:
    import matplotlib.axes

TARGETS = {
    "iou_plain": 0.95,
    "iou_cluttered": 0.90,
    "mpjpe_mm": 80.0,
    "pa_mpjpe_mm": 50.0,
    "reproj_pct": 2.0,
    "psnr_gap_db": 1.5,
    "psnr_gap_track_db": 1.5,
    "psnr_gap_refined_db": 1.5,
    "psnr_gap_polished_db": 1.5,
    "seconds_300": 120.0,
    "peak_gb": 2.0,
}
JOINT_KEYS = ("mpjpe_mm", "pa_mpjpe_mm", "reproj_pct")
"""b and c's figures of a row (and, prefixed ``polished_``, of its polished capture, held to the same targets)."""
TARGETS |= {f"polished_{key}": TARGETS[key] for key in JOINT_KEYS}
BACKGROUNDS = ("plain", "cluttered")
PLAIN_COLOURS = (
    ((118, 128, 138), (168, 156, 136)),
    ((150, 132, 120), (92, 100, 96)),
    ((96, 118, 104), (184, 176, 160)),
)
"""Top and bottom colours of the plain gradient, per seed (cycled): muted walls and floors."""
PHOTOGRAPHS = ("motorcycle", "rocket", "coffee")
"""scikit-image's bundled colour photographs without a person or animal, per seed (cycled)."""
SPEED_FRAMES = 300
SIZE = (512, 384)
"""Width, height of the videos: the "mono" preset's (landscape, as phone videos)."""
PRIOR = ROOT / "assets" / "prior.pt"
PGHM = [sys.executable, "-m", "pghm.cli.main"]
"""The pghm command, run in a child process of this interpreter."""


def photograph(name: str) -> np.ndarray:
    """(h, w, 3) uint8 photograph ``name`` of :data:`PHOTOGRAPHS` from scikit-image's wheel."""
    import skimage.data

    if name == "motorcycle":
        return skimage.data.stereo_motorcycle()[0]
    return getattr(skimage.data, name)()


def cover(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W, 3) uint8: ``image`` scaled to cover W x H, centre-cropped."""
    h, w = image.shape[:2]
    scale = max(width / w, height / h)
    size = (max(width, round(w * scale)), max(height, round(h * scale)))
    scaled = np.asarray(Image.fromarray(image).resize(size, Image.Resampling.LANCZOS))
    top, left = (size[1] - height) // 2, (size[0] - width) // 2
    return np.ascontiguousarray(scaled[top : top + height, left : left + width])


def background(kind: str, seed: int, width: int, height: int) -> np.ndarray:
    if kind == "plain":
        top, bottom = PLAIN_COLOURS[seed % len(PLAIN_COLOURS)]
        return graded_background(top, bottom, width, height)
    return cover(photograph(PHOTOGRAPHS[seed % len(PHOTOGRAPHS)]), width, height)


# ------------------------------------------------------------------ running pghm capture


@dataclass(frozen=True)
class CaptureRun:
    """One ``pghm capture`` child process: its subject, wall time and peak resident memory."""

    subject: Path
    seconds: float
    peak_gb: float


def run_capture(video: Path, out: Path, log: Path, options: tuple[str, ...] = ()) -> CaptureRun:
    """``pghm capture VIDEO --out OUT`` in a child process, so its peak memory is its own (with
    the ffmpeg reader it waits for)."""
    seconds, peak_gb = timed_child([*PGHM, "capture", str(video), "--out", str(out), *options], log)
    return CaptureRun(out, seconds, peak_gb)


# ------------------------------------------------------------------ subject pixels <-> video pixels


@dataclass(frozen=True)
class Crop:
    """The capture's crop (``pghm.capture.crop``): ``region`` of the video frame resized to ``size`` (H', W')."""

    region: Region
    size: tuple[int, int]

    @classmethod
    def of(cls, subject: Subject) -> Crop:
        """The crop recorded in the subject's meta.json; the images' size."""
        crop = subject.meta["crop"]
        region = Region(int(crop["x"]), int(crop["y"]), int(crop["width"]), int(crop["height"]))
        return cls(region, (int(subject.arrays.height[0]), int(subject.arrays.width[0])))

    def to_source(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) subject pixel positions -> source-video pixel positions."""
        return from_region(points, self.region, self.size)

    def to_subject_K(self, K: np.ndarray) -> np.ndarray:  # noqa: N802, N803
        """(n, 3, 3) source intrinsics -> the subject images'."""
        return np.stack([crop_intrinsics(k, self.region, self.size) for k in K])

    def box(self) -> tuple[int, int, int, int]:
        r = self.region
        return r.x, r.y, r.x + r.width, r.y + r.height

    def mask_to_source(self, mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """(H, W) bool source-video mask of a (H', W') subject mask (nearest resampling)."""
        r = self.region
        pasted = Image.fromarray(mask.astype(np.uint8) * 255).resize((r.width, r.height), Image.Resampling.NEAREST)
        out = np.zeros(size, dtype=bool)
        out[r.y : r.y + r.height, r.x : r.x + r.width] = np.asarray(pasted) > 0
        return out

    def image_to_subject(self, image: np.ndarray) -> np.ndarray:
        """(H', W', ...) the crop of a source image or bool mask, resized (bilinear; nearest for masks)."""
        is_mask = image.dtype == bool
        pixels = image.astype(np.uint8) * 255 if is_mask else image
        resample = Image.Resampling.NEAREST if is_mask else Image.Resampling.BILINEAR
        region = Image.fromarray(pixels).crop(self.box()).resize(self.size[::-1], resample)
        return np.asarray(region) > 0 if is_mask else np.asarray(region)


# ------------------------------------------------------------------ measuring against the truth


def read_video(path: Path, frames: set[int]) -> dict[int, np.ndarray]:
    """(H, W, 3) uint8 frames of the video at the indices ``frames``, upright and in SDR as capture reads them."""
    from pghm.capture.crop import Region
    from pghm.capture.video import open_source

    source = open_source(path)
    size = (source.height, source.width)
    read = source.frames(Region.full(source.width, source.height), size, max_frames=max(frames) + 1)
    return {i: image.copy() for i, image in read if i in frames}


def person_height_px(masks: np.ndarray) -> np.ndarray:
    """(F,) rows spanned by each (F, H, W) mask, top of the first to bottom of the last row."""
    rows = masks.any(axis=2)
    first = rows.argmax(axis=1)
    last = rows.shape[1] - rows[:, ::-1].argmax(axis=1)
    return (last - first).astype(np.float64)


@dataclass(frozen=True)
class Comparison:
    """A captured subject against the truth, in source-video pixels.

    Attributes:
        frames: (n,) source frame of each captured image.
        crop: the capture's crop.
        true_uv: (n, N, 2) true canonical joints projected by the true camera.
        captured_uv: (n, N, 2) captured joints projected by the captured camera, mapped to source pixels.
        metrics: the summary (a-c) and per-frame values.
    """

    frames: np.ndarray
    crop: Crop
    true_uv: np.ndarray
    captured_uv: np.ndarray
    metrics: dict


def measure(truth: WalkTruth, subject_dir: Path) -> Comparison:
    """Metrics a-c of the module docstring for one captured subject."""
    from pghm.body import load_body
    from pghm.capture.metrics import camera_joints, error_2d_percent, mapped_joints, mpjpe, pa_mpjpe, project
    from pghm.subject import image_name

    subject = Subject.open(subject_dir)
    a, t = subject.arrays, truth.arrays
    frames = np.asarray(a.frame_index, dtype=np.int64)
    crop = Crop.of(subject)
    total, size = len(truth.masks), truth.masks.shape[1:]
    ious = np.zeros(total)
    for i, frame in enumerate(frames):
        captured = crop.mask_to_source(read_mask(subject_dir / "masks" / image_name(i)) > 0.5, size)
        true = truth.masks[frame]
        ious[frame] = (captured & true).sum() / max((captured | true).sum(), 1)

    body = load_body("anny")
    root = mapped_joints(body)[0].index("pelvis")
    true_cam = camera_joints(
        body, t.shape, t.rotations_true[frames], t.translation_true[frames], t.world_to_camera[frames]
    )
    cap_cam = camera_joints(body, a.shape, a.rotations, a.translation, a.world_to_camera)
    true_uv = project(true_cam, t.K[frames])
    cap_uv = crop.to_source(project(cap_cam, a.K))
    height = person_height_px(truth.masks[frames])
    per_frame = [
        (
            mpjpe(cap_cam[[k]], true_cam[[k]], root),
            pa_mpjpe(cap_cam[[k]], true_cam[[k]]),
            error_2d_percent(cap_uv[[k]], true_uv[[k]], height[[k]]),
        )
        for k in range(len(frames))
    ]
    mpjpe_m, pa_mpjpe_m, reproj_pct = (np.array(column) for column in zip(*per_frame))
    metrics = {
        "frames": total,
        "kept": len(frames),
        "iou": float(ious.mean()),
        "iou_kept": float(ious[frames].mean()),
        "mpjpe_mm": float(1000 * mpjpe_m.mean()),
        "pa_mpjpe_mm": float(1000 * pa_mpjpe_m.mean()),
        "reproj_pct": float(reproj_pct.mean()),
        "per_frame": {
            "frame": frames.tolist(),
            "iou": ious[frames].round(4).tolist(),
            "mpjpe_mm": (1000 * mpjpe_m).round(1).tolist(),
            "pa_mpjpe_mm": (1000 * pa_mpjpe_m).round(1).tolist(),
            "reproj_pct": reproj_pct.round(2).tolist(),
        },
    }
    return Comparison(frames, crop, true_uv, cap_uv, metrics)


# ------------------------------------------------------------------ d. the avatar fitted on the capture


def reference_subject(truth: WalkTruth, video: Path, captured_dir: Path, out: Path, true_masks: bool) -> Path:
    """The captured subject's frames, crop and split with the true poses and cameras; its images
    and masks, or with ``true_masks`` the true masks.

    K is the true intrinsics through the crop, world_to_camera the true (moving) camera. With
    ``true_masks`` the images are the decoded video frames (the same compression) composited on
    white through the true masks, cropped as the capture cropped.
    """
    from pghm.subject import SubjectArrays, write_image, write_subject

    captured = Subject.open(captured_dir)
    a, t = captured.arrays, truth.arrays
    frames = np.asarray(a.frame_index, dtype=np.int64)
    crop = Crop.of(captured)
    if true_masks:
        decoded = read_video(video, set(frames.tolist()))
        for i, frame in enumerate(frames):
            mask = crop.image_to_subject(truth.masks[frame])
            rgb = np.where(mask[..., None], crop.image_to_subject(decoded[frame]), 255).astype(np.uint8)
            write_image(out, i, rgb, mask.astype(np.uint8) * 255)
    else:
        for folder in ("images", "masks"):
            shutil.copytree(Path(captured_dir) / folder, out / folder)
    arrays = SubjectArrays(
        K=crop.to_subject_K(t.K[frames]),
        world_to_camera=t.world_to_camera[frames],
        height=a.height,
        width=a.width,
        rotations=t.rotations_true[frames],
        translation=t.translation_true[frames],
        shape=t.shape,
        body=t.body,
        bone_names=t.bone_names,
        splits=a.splits,
        frame_index=frames,
        view_index=np.zeros(len(frames), dtype=np.int64),
    )
    truths = "true masks, poses and cameras" if true_masks else "the capture's masks; true poses and cameras"
    write_subject(out, arrays, {"source": f"bench_capture reference: {truths}"})
    return out


REFINE_STEPS = 30
"""Test-time pose refinement steps of d's second evaluation (``pghm eval --refine-poses``)."""


EVALUATIONS = {"": [], "track_": ["--fit-poses"], "refined_": ["--refine-poses", str(REFINE_STEPS)]}
"""d's three evaluations of an avatar (report prefix: ``pghm eval`` options): the stored poses, the
fit's pose track, the poses refined against the test images."""


def fit_and_eval(subject_dir: Path, avatar: Path) -> dict:
    """``pghm fit`` (defaults, the shipped prior) then ``pghm eval --split test`` three times
    (:data:`EVALUATIONS`); summaries and seconds.

    An avatar or report already in a ``--keep`` folder is reused (``pghm fit`` and ``pghm eval``
    write whole files or none), so an interrupted d run resumes where it stopped; its fit's
    seconds are those recorded beside it (``None`` when it was not recorded).
    """
    timing = avatar.with_suffix(".fit_seconds.json")
    if not avatar.exists():
        started = time.perf_counter()
        subprocess.run([*PGHM, "fit", str(subject_dir), "--prior", str(PRIOR), "--out", str(avatar)], check=True)
        timing.write_text(json.dumps(round(time.perf_counter() - started, 1)))
    out = {"fit_seconds": json.loads(timing.read_text()) if timing.exists() else None}
    return out | evaluate(avatar, subject_dir, avatar.with_suffix(""), EVALUATIONS)


def evaluate(avatar: Path, subject_dir: Path, reports: Path, evaluations: dict[str, list[str]]) -> dict:
    """``pghm eval --split test`` of ``avatar`` on ``subject_dir``, once per entry of ``evaluations``
    (its report ``reports.{prefix}eval.json`` and strip ``.png``, reused when present); each one's PSNR
    and SSIM."""
    out = {}
    for name, poses in evaluations.items():
        report = reports.with_name(f"{reports.name}.{name}eval.json")
        if not report.exists():
            evaluation = [*PGHM, "eval", str(avatar), str(subject_dir), "--split", "test", "--report", str(report)]
            subprocess.run([*evaluation, "--strip", str(report.with_suffix(".png")), *poses], check=True)
        summary = json.loads(report.read_text())["mean"]
        out.update({f"{name}psnr": float(summary["psnr"]), f"{name}ssim": float(summary["ssim"])})
    return out


def same_training_split(a: Path, b: Path) -> bool:
    """Whether ``pghm fit`` sees the same data in subject folders ``a`` and ``b``: the same splits,
    cameras, shape and stated pose noise, and the same poses, images and masks of the training
    frames (:mod:`pghm.capture.polish` changes only the held-out frames' poses)."""
    from pghm.subject import image_name

    first, second = Subject.open(a), Subject.open(b)
    x, y = first.arrays, second.arrays
    train = x.splits.get("train", [])
    if x.splits != y.splits or first.meta.get("pose_noise") != second.meta.get("pose_noise"):
        return False
    for name in ("K", "world_to_camera", "shape"):
        if not np.array_equal(getattr(x, name), getattr(y, name)):
            return False
    if not all(np.array_equal(getattr(x, n)[train], getattr(y, n)[train]) for n in ("rotations", "translation")):
        return False
    files = [f"{folder}/{image_name(i)}" for folder in ("images", "masks") for i in train]
    return all((a / f).read_bytes() == (b / f).read_bytes() for f in files)


def held_out_joints(metrics: dict, frames: list[int]) -> dict:
    """b and c (:data:`JOINT_KEYS`) of the source frames ``frames`` alone, from ``measure``'s per-frame figures."""
    per_frame = metrics["per_frame"]
    rows = [per_frame["frame"].index(f) for f in frames]
    return {key: float(np.mean([per_frame[key][k] for k in rows])) for key in JOINT_KEYS}


# ------------------------------------------------------------------ figures

MASK_COLOURS = {"both": (255, 255, 255), "missed": (230, 60, 60), "extra": (60, 120, 240)}
"""Mask comparison: true and captured (white), true only (red), captured only (blue)."""
TRUE_COLOUR, CAPTURED_COLOUR = (40, 220, 90), (255, 60, 200)
TILE_SCALE = 0.5
"""Tiles of the frames figure at half the video's size."""


def canonical_parents() -> list[int]:
    """Parent of each canonical joint: its nearest canonical ancestor in the body's bone tree (-1: none)."""
    from pghm.body import load_body
    from pghm.capture.metrics import mapped_joints

    body = load_body("anny")
    names = mapped_joints(body)[0]
    index = {body.joint_map[name]: k for k, name in enumerate(names)}
    parents = []
    for name in names:
        bone = body.parents[body.joint_map[name]]
        while bone >= 0 and bone not in index:
            bone = body.parents[bone]
        parents.append(index.get(bone, -1))
    return parents


def draw_skeleton(image: Image.Image, uv: np.ndarray, colour: tuple[int, int, int], parents: list[int]) -> None:
    from PIL import ImageDraw

    draw = ImageDraw.Draw(image)
    for k, parent in enumerate(parents):
        if parent >= 0:
            draw.line([tuple(uv[k]), tuple(uv[parent])], fill=colour, width=2)
        draw.ellipse([uv[k][0] - 2, uv[k][1] - 2, uv[k][0] + 2, uv[k][1] + 2], fill=colour)


def frame_tiles(truth: WalkTruth, video: Path, subject_dir: Path, comparison: Comparison) -> np.ndarray:
    """(h, 3 w, 3) uint8 of the middle captured frame: video | masks compared | joints (true, captured)."""
    from pghm.subject import image_name

    i = len(comparison.frames) // 2
    frame = int(comparison.frames[i])
    decoded = read_video(video, {frame})[frame]
    true = truth.masks[frame]
    captured = comparison.crop.mask_to_source(read_mask(subject_dir / "masks" / image_name(i)) > 0.5, true.shape)
    masks = np.zeros_like(decoded)
    for key, region in (("both", true & captured), ("missed", true & ~captured), ("extra", captured & ~true)):
        masks[region] = MASK_COLOURS[key]
    joints = Image.fromarray(decoded)
    parents = canonical_parents()
    draw_skeleton(joints, comparison.true_uv[i], TRUE_COLOUR, parents)
    draw_skeleton(joints, comparison.captured_uv[i], CAPTURED_COLOUR, parents)
    row = np.concatenate([decoded, masks, np.asarray(joints)], axis=1)
    size = (round(row.shape[1] * TILE_SCALE), round(row.shape[0] * TILE_SCALE))
    return np.asarray(Image.fromarray(row).resize(size, Image.Resampling.LANCZOS))


def plot_metrics(rows: list[dict], path: Path) -> None:
    """One panel per metric: each seed x background against its target (b and c of a polished
    capture's test frames, before and after the polish, as diamonds over the bars)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r['background']}\nseed {r['seed']}" for r in rows]
    colours = ["#4c9be8" if r["background"] == "plain" else "#e8914c" for r in rows]
    x = np.arange(len(rows))
    panels = [
        ("mask IoU", "iou", [("plain", TARGETS["iou_plain"]), ("cluttered", TARGETS["iou_cluttered"])], "higher"),
        ("MPJPE (mm), root-relative", "mpjpe_mm", [("", TARGETS["mpjpe_mm"])], "lower"),
        ("PA-MPJPE (mm)", "pa_mpjpe_mm", [("", TARGETS["pa_mpjpe_mm"])], "lower"),
        ("2D joint error (% of height)", "reproj_pct", [("", TARGETS["reproj_pct"])], "lower"),
    ]
    gaps = all("psnr_gap_db" in r for r in rows)
    figure, axes = plt.subplots(1, len(panels) + gaps, figsize=(4.2 * (len(panels) + gaps), 3.6))
    if gaps:
        gap_panel(axes[-1], rows, labels)
    for ax, (title, key, targets, better) in zip(axes, panels):
        ax.bar(x, [r[key] for r in rows], color=colours)
        for which, filled, name in (("unpolished", "none", "test frames as captured"), ("polished", "k", "--polish")):
            if any(f"{which}_{key}" in r for r in rows):
                values = [r.get(f"{which}_{key}", np.nan) for r in rows]
                ax.plot(x, values, "D", color="k", markerfacecolor=filled, markersize=5, linestyle="none", label=name)
                ax.legend(fontsize=7, loc="lower right")
        for name, value in targets:
            ax.axhline(value, color="k", linestyle="--", linewidth=1)
            ax.text(len(rows) - 0.5, value, f" target {name}".rstrip(), va="bottom", ha="right", fontsize=8)
        ax.set_title(f"{title} ({better} is better)", fontsize=10)
        ax.set_xticks(x, labels, fontsize=7)
        if key == "iou":
            ax.set_ylim(min(0.8, min(r[key] for r in rows) - 0.02), 1.0)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


GAP_BARS = (
    ("psnr_gap_db", "stored poses", "#9aa3ad"),
    ("psnr_gap_track_db", "fit poses", "#4c9be8"),
    ("psnr_gap_refined_db", "refined poses", "#3bb273"),
    ("psnr_gap_polished_db", "polished capture, stored poses", "#e8a33b"),
)
"""d's three gaps per case: the key, its legend and its colour."""


def gap_panel(ax: matplotlib.axes.Axes, rows: list[dict], labels: list[str]) -> None:
    """d: each case's PSNR gap to its true-pose reference, with the stored, fit and refined poses."""
    x, width = np.arange(len(rows)), 0.8 / len(GAP_BARS)
    for i, (key, name, colour) in enumerate(GAP_BARS):
        offset = (i - (len(GAP_BARS) - 1) / 2) * width  # the bars of a case side by side, centred on it
        ax.bar(x + offset, [r.get(key, np.nan) for r in rows], width, color=colour, label=name)
    ax.axhline(TARGETS["psnr_gap_db"], color="k", linestyle="--", linewidth=1)
    ax.axhline(0.0, color="k", linewidth=0.5)
    ax.text(len(rows) - 0.5, TARGETS["psnr_gap_db"], "target", va="bottom", ha="right", fontsize=8)
    ax.set_title("d. PSNR gap to the true-pose fit, dB (lower is better)", fontsize=10)
    ax.set_xticks(x, labels, fontsize=7)
    ax.legend(fontsize=7)


# ------------------------------------------------------------------ main


def capture_case(
    work: Path,
    seed: int,
    kind: str,
    frames: int,
    fit: bool,
    motion: str = "walk",
    true_masks: bool = True,
    polish: bool = False,
    given_height: bool = False,
) -> tuple[dict, np.ndarray]:
    """Video, capture, metrics (and the fits with ``fit``) of one seed x background: the row and its tiles.

    d's second reference (the true masks too) is fitted only with ``true_masks``; with ``polish``, d
    also captures the video with ``--polish`` (the shipped prior) and fits and scores that subject;
    with ``given_height``, the capture is told the walker's true height (``--height``), as a user
    who knows theirs would.
    """
    import torch

    from pghm.body import load_body
    from pghm.capture.bodyfit import rest_height

    name = f"{kind}_{seed}_{frames}f" if motion == "walk" else f"{motion}_{kind}_{seed}_{frames}f"
    video = work / f"{name}.mp4"
    config = walk_config(frames, *SIZE, motion=motion)
    truth = render_walk_video(config, seed, video, background(kind, seed, *SIZE), progress=True)
    subject_dir = work / name
    shutil.rmtree(subject_dir, ignore_errors=True)  # a --keep folder's subjects are made again; its fits are reused
    body = load_body("anny")
    true_height = rest_height(body, torch.as_tensor(truth.arrays.shape))
    options = ("--every", "1") + (("--height", f"{true_height:.3f}") if given_height else ())  # the truth: every frame
    run = run_capture(video, subject_dir, work / f"{name}.log", options)
    comparison = measure(truth, subject_dir)
    row = {
        "motion": motion,
        "background": kind,
        "seed": seed,
        "frames": frames,
        **{k: v for k, v in comparison.metrics.items() if k != "per_frame"},
        "check_problems": len(check(subject_dir)),
        "true_height_m": round(true_height, 3),
        "height_m": round(rest_height(body, torch.as_tensor(Subject.open(subject_dir).arrays.shape)), 3),
        "given_height": given_height,
        "capture_s": round(run.seconds, 1),
        "peak_gb": round(run.peak_gb, 2),
        "per_frame": comparison.metrics["per_frame"],
    }
    if fit:
        row["fit"] = {"captured": fit_and_eval(subject_dir, work / f"{kind}_{seed}_captured.pt")}
        references = [("poses", False), ("all", True)] if true_masks else [("poses", False)]
        for which, with_true_masks in references:
            reference = work / f"{kind}_{seed}_{frames}f_true_{which}"
            shutil.rmtree(reference, ignore_errors=True)
            reference_subject(truth, video, subject_dir, reference, with_true_masks)
            row["fit"][f"true_{which}"] = fit_and_eval(reference, work / f"{kind}_{seed}_true_{which}.pt")
        captured, poses = row["fit"]["captured"], row["fit"]["true_poses"]
        row["psnr_gap_db"] = round(poses["psnr"] - captured["psnr"], 2)
        # Against the reference's own poses: they are the true ones, its track corrects only noise.
        row["psnr_gap_track_db"] = round(poses["psnr"] - captured["track_psnr"], 2)
        row["psnr_gap_refined_db"] = round(poses["refined_psnr"] - captured["refined_psnr"], 2)
        if polish:
            polished = work / f"{name}_polished"
            if not polished.exists():  # written whole or not at all: a --keep folder's is reused
                run_capture(video, polished, work / f"{name}_polished.log", ("--every", "1", "--polish", str(PRIOR)))
            meta = json.loads((polished / "meta.json").read_text())
            row["polish"], aligned = meta["polish"], meta["aligned_frames"]
            # b and c of the frames the polish aligned, before and after (the others are as captured).
            row.update({f"unpolished_{k}": v for k, v in held_out_joints(comparison.metrics, aligned).items()})
            joints = held_out_joints(measure(truth, polished).metrics, aligned)
            row.update({f"polished_{key}": joints[key] for key in JOINT_KEYS})
            if same_training_split(subject_dir, polished):
                # pghm fit reads only the training frames, which the polish left as captured: its
                # avatar is the captured subject's (its pose track is of the other poses: no track_).
                row["polish"]["fit"] = "the captured subject's (same training frames)"
                unchanged = {k: v for k, v in EVALUATIONS.items() if k != "track_"}
                captured_avatar = work / f"{kind}_{seed}_captured.pt"
                reports = work / f"{kind}_{seed}_captured_on_polished"
                row["fit"]["polished"] = evaluate(captured_avatar, polished, reports, unchanged)
            else:
                row["fit"]["polished"] = fit_and_eval(polished, work / f"{kind}_{seed}_polished.pt")
            row["psnr_gap_polished_db"] = round(poses["psnr"] - row["fit"]["polished"]["psnr"], 2)
        if true_masks:
            every = row["fit"]["true_all"]
            row["psnr_gap_all_db"] = round(every["psnr"] - captured["psnr"], 2)
            row["psnr_gap_all_refined_db"] = round(every["refined_psnr"] - captured["refined_psnr"], 2)
    return row, frame_tiles(truth, video, subject_dir, comparison)


def stage_seconds(video: Path, folder: Path) -> dict:
    """The pipeline's two stages on ``video``, timed apart: front end (both passes), body fit.

    Runs inside the child process of :func:`speed_case` (``--stages``): the same calls
    ``pghm.capture.capture`` makes, without writing the arrays.
    """
    from pghm.capture.bodyfit import fit_body
    from pghm.capture.config import CaptureConfig
    from pghm.capture.pipeline import observe_video

    folder.mkdir(parents=True, exist_ok=True)  # a --keep folder of an earlier run is reused
    started = time.perf_counter()
    front = observe_video(video, folder, CaptureConfig(progress=False, every=1))  # e: every frame
    front_s = time.perf_counter() - started
    fit_body(front.observations)
    return {"front_end_s": round(front_s, 1), "body_fit_s": round(time.perf_counter() - started - front_s, 1)}


def speed_case(work: Path, frames: int) -> dict:
    """e: a ``frames``-frame 512-px plain video through the pipeline's stages in a child process.

    Wall time of each stage from the child; peak resident memory of the child (``os.wait4``:
    ru_maxrss, kB, of the child and the ffmpeg readers it waited for).
    """
    video = work / f"speed_{frames}f.mp4"
    if not video.exists():  # a --keep folder's video is reused: it is only read here
        render_walk_video(walk_config(frames, *SIZE), 0, video, background("plain", 0, *SIZE), progress=True)
    load = load_average()
    log = work / f"speed_{frames}f.log"
    command = [sys.executable, str(Path(__file__).resolve()), "--stages", str(video), str(work / f"speed_{frames}f")]
    with open(log, "w") as sink:
        process = subprocess.Popen(command, stdout=sink, stderr=subprocess.DEVNULL)
        _, status, usage = os.wait4(process.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"the stage timing of {video.name} failed:\n{log.read_text()[-1500:]}")
    stages = json.loads(log.read_text().strip().splitlines()[-1])
    return {
        "frames": frames,
        "size": f"{SIZE[0]}x{SIZE[1]}",
        **stages,
        "seconds": round(stages["front_end_s"] + stages["body_fit_s"], 1),
        "peak_gb": round(usage.ru_maxrss * KB / BYTES_PER_GB, 2),
        "load_before": round(load, 2),
    }


HELD_OUT_SEEDS = frozenset({3})
"""Seeds no setting of the capture was chosen on: in the table and the per-video verdicts, left out of
the means over the tuned seeds."""
GAP_KEYS = ("psnr_gap_db", "psnr_gap_track_db", "psnr_gap_refined_db", "psnr_gap_polished_db")
"""d's gaps, judged against the true-pose reference's fit."""


def _meets(key: str, value: float) -> bool:
    return value >= TARGETS[key] if key.startswith("iou") else value <= TARGETS[key]


def _judged(rows: list[dict]) -> dict[str, list[tuple[str, float]]]:
    """Each target's (background, value) pairs, one per row that measured it."""
    out = {f"iou_{r['background']}": [] for r in rows}
    for r in rows:
        out[f"iou_{r['background']}"].append((r["background"], r["iou"]))
        for key in (*JOINT_KEYS, *(f"polished_{k}" for k in JOINT_KEYS), *GAP_KEYS):
            if key in r:
                out.setdefault(key, []).append((r["background"], r[key]))
    return out


def verdicts(rows: list[dict], speed: dict | None) -> dict[str, bool]:
    """Each target of the module docstring, judged three ways: met by every video of the tuned seeds
    (``key``), by the mean over those videos of each background (``mean_key``: published figures
    are means over a data set), and by every held-out video (``held_out_key``, :data:`HELD_OUT_SEEDS`)."""
    tuned = [r for r in rows if r["seed"] not in HELD_OUT_SEEDS]
    held_out = [r for r in rows if r["seed"] in HELD_OUT_SEEDS]
    out = {key: all(_meets(key, v) for _, v in values) for key, values in _judged(tuned).items()}
    for key, values in _judged(tuned).items():
        means = [np.mean([v for b, v in values if b == kind]) for kind in sorted({b for b, _ in values})]
        out[f"mean_{key}"] = all(_meets(key, float(m)) for m in means)
    for key, values in _judged(held_out).items():
        out[f"held_out_{key}"] = all(_meets(key, v) for _, v in values)
    if speed is not None:
        out["seconds_300"] = speed["seconds"] <= TARGETS["seconds_300"]
        out["peak_gb"] = speed["peak_gb"] <= TARGETS["peak_gb"]
    return out


VERDICT_PREFIXES = {
    "": "every video of the tuned seeds",
    "mean_": "mean over the tuned seeds of each background",
    "held_out_": "every held-out video",
}
"""How a verdict key's prefix judged its target (:func:`verdicts`)."""


def background_means(rows: list[dict]) -> list[dict]:
    """One row per background: the mean of each figure over the tuned seeds' rows (:data:`HELD_OUT_SEEDS` left out)."""
    out = []
    for kind in sorted({r["background"] for r in rows}):
        tuned = [r for r in rows if r["background"] == kind and r["seed"] not in HELD_OUT_SEEDS]
        if not tuned:
            continue
        keys = [k for k in tuned[0] if isinstance(tuned[0][k], (int, float)) and k not in ("seed", "frames")]
        mean = {
            k: round(float(np.mean([r[k] for r in tuned if k in r])), 3) for k in keys if all(k in r for r in tuned)
        }
        out.append({"background": kind, "seed": "mean " + ",".join(str(r["seed"]) for r in tuned), **mean})
    return out


def report(
    args: argparse.Namespace, rows: list[dict], tiles: list[np.ndarray], speed: dict | None, load: float
) -> None:
    """Print the table and verdicts; write the JSON and (with rows) the figures."""
    if rows:
        columns = ["background", "seed", "kept", "iou", "mpjpe_mm", "pa_mpjpe_mm", "reproj_pct", "capture_s", "peak_gb"]
        if any(r.get("motion", "walk") != "walk" for r in rows):
            columns.insert(0, "motion")
        if any("psnr_gap_db" in r for r in rows):
            columns += ["psnr_gap_db", "psnr_gap_track_db", "psnr_gap_refined_db", "psnr_gap_all_db"]
            columns += ["psnr_gap_all_refined_db", "psnr_gap_polished_db"]
        if any("psnr_gap_polished_db" in r for r in rows):
            columns += [f"{which}_{key}" for key in JOINT_KEYS for which in ("unpolished", "polished")]
        print_table(rows + background_means(rows), columns)
        figure = figure_name(args.results)
        plot_metrics(rows, DOCS / f"{figure}.png")
        print(f"wrote docs/{figure}.png")
        if tiles:
            Image.fromarray(np.concatenate(tiles, axis=0)).save(DOCS / f"{figure}_frames.png")
            print(f"wrote docs/{figure}_frames.png")
    if speed is not None:
        print_table([speed], ["frames", "size", "front_end_s", "body_fit_s", "seconds", "peak_gb", "load_before"])
    passed = verdicts(rows, speed)
    for key, ok in passed.items():
        prefix = next((p for p in VERDICT_PREFIXES if p and key.startswith(p)), "")
        target, judged = TARGETS[key.removeprefix(prefix)], VERDICT_PREFIXES[prefix]
        print(f"{key}: target {target} ({judged}): {'PASS' if ok else 'FAIL'}")
    write_json(
        args.results,
        {
            "targets": TARGETS,
            "rows": rows,
            "speed": speed,
            "means": background_means(rows),
            "verdicts": passed,
            "load_before": load,
            "load_after": load_average(),
            "command": " ".join(["python", "benchmarks/bench_capture.py", *shown_arguments(sys.argv[1:])]),
        },
    )


def shown_arguments(argv: list[str]) -> list[str]:
    """The command line as a report records it: the --keep folder (a path of this machine) as DIR."""
    return ["DIR" if previous == "--keep" else argument for previous, argument in zip(["", *argv], argv)]


def figure_name(results: str) -> str:
    return results.replace("bench_capture", "capture_bench")


def combine(args: argparse.Namespace) -> None:
    """Report the rows, speed and frame figures of the runs ``args.combine`` as one run, ``args.results``."""
    rows, tiles, speed, loads = [], [], None, []
    for name in args.combine:
        run = json.loads((RESULTS / f"{name}.json").read_text())
        rows += run["rows"]
        speed = run["speed"] or speed
        loads.append(run["load_before"])
        frames = DOCS / f"{figure_name(name)}_frames.png"
        if run["rows"] and frames.exists():
            tiles.append(np.asarray(Image.open(frames).convert("RGB")))
        elif run["rows"]:  # made on another machine: docs/ keeps only the joined figures
            print(f"{frames.relative_to(ROOT)} is not here: the joined frames figure leaves {name} out")
    report(args, rows, tiles, speed, max(loads))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2], help="none: the speed case only")
    parser.add_argument("--backgrounds", nargs="+", choices=BACKGROUNDS, default=list(BACKGROUNDS))
    parser.add_argument("--frames", type=int, default=100, help="frames per accuracy video (default %(default)s)")
    parser.add_argument(
        "--motion",
        choices=MOTION_KINDS,
        default="walk",
        help="what the person does: the targets are set for the walk; the others, on the spot, check the "
        "body fit's pose prior on motions it was not learned from (default %(default)s)",
    )
    parser.add_argument(
        "--speed-frames",
        type=int,
        default=SPEED_FRAMES,
        help="frames of the speed video, 0 to skip (default %(default)s)",
    )
    parser.add_argument(
        "--fit",
        nargs="*",
        default=None,
        metavar="BACKGROUND_SEED",
        help="run d on these cases, e.g. plain_0 cluttered_1 (no value: plain_0); expensive: three fits a case, "
        "the captured one 20-40 min of one core",
    )
    parser.add_argument(
        "--no-true-masks",
        action="store_true",
        help="d without its second reference (true masks as well as true poses): two fits a case, not three",
    )
    parser.add_argument(
        "--polish",
        action="store_true",
        help="d also on the video captured with --polish (the shipped prior): one fit on all frames more a case",
    )
    parser.add_argument(
        "--given-height",
        action="store_true",
        help="tell the capture each walker's true height (--height), as a user who knows theirs would",
    )
    parser.add_argument("--keep", help="keep the videos and subjects here instead of a temporary folder")
    parser.add_argument(
        "--results",
        default="bench_capture",
        help="name of the JSON in benchmarks/results/ and of the figures in docs/ (default %(default)s)",
    )
    parser.add_argument(
        "--combine",
        nargs="+",
        metavar="RESULTS",
        help="measure nothing: join the rows, speed and frame figures of earlier runs (e.g. seeds run in parallel)",
    )
    parser.add_argument("--stages", nargs=2, metavar=("VIDEO", "FOLDER"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.stages:
        print(json.dumps(stage_seconds(Path(args.stages[0]), Path(args.stages[1]))))
        return 0
    if args.combine:
        combine(args)
        return 0
    fit_cases = set(args.fit or ["plain_0"]) if args.fit is not None else set()
    load_before = load_average()
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(args.keep) if args.keep else Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        rows, tiles, speed = [], [], None
        for seed in args.seeds:
            for kind in args.backgrounds:
                fit = f"{kind}_{seed}" in fit_cases
                row, tile = capture_case(
                    work,
                    seed,
                    kind,
                    args.frames,
                    fit,
                    args.motion,
                    not args.no_true_masks,
                    args.polish,
                    args.given_height,
                )
                rows.append(row)
                tiles.append(tile)
                report(args, rows, tiles, speed, load_before)  # each case as it ends: a long run keeps what it measured
        if args.speed_frames:
            speed = speed_case(work, args.speed_frames)
            report(args, rows, tiles, speed, load_before)
    return 0


if __name__ == "__main__":
    sys.exit(main())
