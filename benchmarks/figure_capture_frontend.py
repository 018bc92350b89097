"""docs/capture_frontend.png: the capture front end on a video, a picture per stage.

    python benchmarks/figure_capture_frontend.py [VIDEO] [--frames 4] [--out docs/capture_frontend.png]
                                                 [--subject SUBJECT]

Columns are frames spread over the video; rows are the cropped frame (the region the person
occupies over the video), the mask over it, and MediaPipe's 33 landmarks and skeleton
(marker size by confidence); with ``--subject`` (what ``pghm capture VIDEO`` wrote with the
default options), a fourth row: the fitted body, its mesh rasterised through the subject's
camera with its pose of that frame, over the frame. VIDEO defaults to the real phone video beside the repository
(``shared/data/video/outdoor_dribble_40f.mp4`` in the nearest parent folder holding it).
Prints the per-frame mask fraction and the crop.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import DOCS, ROOT  # noqa: E402

from pghm.capture.config import CaptureConfig  # noqa: E402
from pghm.capture.pipeline import observe_video  # noqa: E402
from pghm.capture.video import open_source  # noqa: E402
from pghm.io.atomic import save_figure  # noqa: E402

REAL_VIDEO = Path("shared") / "data" / "video" / "outdoor_dribble_40f.mp4"
"""The real phone video, in a ``shared/`` folder beside the repository (or beside a parent of it)."""
MASK_TINT = np.array([0.1, 0.6, 1.0])
BODY_TINT = np.array([0.2, 1.0, 0.3])
MASK_ALPHA = 0.5


def skeleton_edges() -> list[tuple[int, int]]:
    from mediapipe.python.solutions.pose_connections import POSE_CONNECTIONS

    return sorted(POSE_CONNECTIONS)


def fitted_body_masks(subject_dir: Path, frame_indices: list[int]) -> dict[int, np.ndarray]:
    """Source frame -> (H, W) bool: the subject's fitted body, its posed mesh projected through the
    subject's camera (pinhole, docs/data.md) and its faces filled."""
    import torch
    from PIL import Image, ImageDraw

    from pghm.body import load_body
    from pghm.subject import Subject

    subject = Subject.open(subject_dir)
    arrays = subject.arrays
    body = load_body(str(arrays.body))
    rest = body.rest(torch.as_tensor(arrays.shape))
    faces = body.faces.numpy()
    image_of = {int(f): i for i, f in enumerate(arrays.frame_index)}
    masks = {}
    for frame in frame_indices:
        i = image_of[frame]
        pose = body.pose_from_arrays(arrays.rotations[i], arrays.translation[i])
        vertices = body.posed_vertices(pose, rest)[0].numpy().astype(np.float64)
        camera = arrays.world_to_camera[i].astype(np.float64)
        points = vertices @ camera[:3, :3].T + camera[:3, 3]
        pixels = points @ arrays.K[i].astype(np.float64).T
        uv = pixels[:, :2] / pixels[:, 2:3] - 0.5  # pixel centres at +0.5 -> PIL's integer grid
        canvas = Image.new("1", (int(arrays.width[i]), int(arrays.height[i])))
        draw = ImageDraw.Draw(canvas)
        for triangle in uv[faces]:
            draw.polygon([tuple(corner) for corner in triangle], fill=1)
        masks[frame] = np.array(canvas, dtype=bool)
    return masks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = next((str(p / REAL_VIDEO) for p in ROOT.parents if (p / REAL_VIDEO).is_file()), None)
    parser.add_argument("video", nargs="?", default=default)
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--out", default=str(DOCS / "capture_frontend.png"))
    parser.add_argument("--subject", type=Path, default=None, help="the subject pghm capture wrote from VIDEO")
    args = parser.parse_args()
    config = CaptureConfig(progress=False)
    with tempfile.TemporaryDirectory() as folder:
        front = observe_video(args.video, Path(folder), config)
        obs = front.observations
        picks = np.linspace(0, len(obs.frame_index) - 1, args.frames).round().astype(int)
        wanted = {int(obs.frame_index[k]): k for k in picks}
        frames = {}
        source = open_source(args.video)
        for index, image in source.frames(front.region, obs.image_size, front.every, config.max_frames):
            if index in wanted:
                frames[index] = image.copy()
        masks = {k: np.array(obs.masks[k]) for k in picks}
    fractions = [float(masks[k].mean()) for k in picks]
    print(f"{front.source_name}: {len(obs.frame_index)}/{front.frames_read} frames kept, crop {front.region}")
    print("mask fraction of the cropped frame per shown frame:", [f"{f:.3f}" for f in fractions])

    edges = skeleton_edges()
    bodies = fitted_body_masks(args.subject, [int(obs.frame_index[k]) for k in picks]) if args.subject else {}
    labels = ("frame (cropped)", "mask", "landmarks") + (("fitted body",) if bodies else ())
    rows = len(labels)
    fig, axes = plt.subplots(
        rows, len(picks), figsize=(2.6 * len(picks), rows * 2.6 * obs.image_size[0] / obs.image_size[1])
    )
    for column, k in enumerate(picks):
        index = int(obs.frame_index[k])
        image = frames[index].astype(np.float64) / 255
        mask = masks[k][..., None]
        tinted = np.where(mask, (1 - MASK_ALPHA) * image + MASK_ALPHA * MASK_TINT, image * 0.6)
        axes[0, column].imshow(image)
        axes[0, column].set_title(f"frame {index}", fontsize=9)
        axes[1, column].imshow(tinted)
        axes[2, column].imshow(image * 0.7)
        points, confidence = obs.landmarks_2d[k] - 0.5, obs.confidence[k]  # pixel centres -> imshow's
        for a, b in edges:
            axes[2, column].plot(*points[[a, b]].T, color="yellow", linewidth=1)
        axes[2, column].scatter(*points.T, s=4 + 10 * confidence, c=confidence, cmap="autumn", vmin=0, vmax=1)
        if bodies:
            body = bodies[index][..., None]
            axes[3, column].imshow(np.where(body, (1 - MASK_ALPHA) * image + MASK_ALPHA * BODY_TINT, image))
            overlap = (bodies[index] & masks[k]).sum() / max((bodies[index] | masks[k]).sum(), 1)
            axes[3, column].set_title(f"body vs mask IoU {overlap:.2f}", fontsize=8)
        for row in range(rows):
            axes[row, column].set_axis_off()
    for row, label in enumerate(labels):
        axes[row, 0].text(-0.05, 0.5, label, transform=axes[row, 0].transAxes, rotation=90, ha="right", va="center")
    fig.tight_layout()
    save_figure(fig, args.out, dpi=110)
    print(f"wrote {Path(args.out).relative_to(ROOT) if Path(args.out).is_relative_to(ROOT) else args.out}")


if __name__ == "__main__":
    sys.exit(main())
