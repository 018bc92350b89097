"""Synthetic monocular walks written as H.264 videos over a background: truth for ``pghm capture``.

    config = walk_config(frames=100)                          # the "mono" preset, one walk, no test images
    truth = render_walk_video(config, seed=0, out="walk.mp4", background=graded_background(...))
    truth.arrays      # SubjectArrays of the video's frames: K, world_to_camera, rotations_true, ...
    truth.masks       # (F, H, W) bool, the true masks

Frame f of the video is time step f of the generator's monocular plan (subject 0 of
``seed``, main camera): the config has no test frames and no novel views, so the video is
one continuous walk filmed by the slowly panning camera.

The person is composited over the background through its anti-aliased coverage. The
renderer gives rgb = c a + (1 - a) (colour c on white, coverage a), so over a background b

    out = c a + (1 - a) b = rgb - (1 - a) (1 - b).

Encoding: H.264 (libx264), yuv420p (the 4:2:0 chroma phones record), constant rate
factor :data:`VIDEO_CRF`, so the capture sees compression as it would in a real video.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pghm.body import load_body
from pghm.errors import PghmError
from pghm.io.atomic import atomic_path
from pghm.subject import SubjectArrays
from pghm.synth.config import PRESETS, SynthConfig
from pghm.synth.generate import plan_subject, release_worker_gl, render_views
from pghm.synth.render import MASK_COVERAGE, RenderedView

VIDEO_CRF = 23
"""libx264's constant rate factor (its default): visible blocking at edges and in flat
gradients, the quality of a phone's recording after sharing."""

SUBJECT_INDEX = 0
"""The video films subject 0 of the seed (its random streams, as ``pghm synth``'s)."""


@dataclass(frozen=True)
class WalkTruth:
    """The generator's truth for every frame of a walk video.

    Attributes:
        arrays: the plan's arrays, image i = video frame i: K (F, 3, 3), world_to_camera
            (F, 4, 4), rotations_true (F, J, 3), translation_true (F, 3), shape (S,), ...
        masks: (F, H, W) bool, the person's true mask (coverage >= half a pixel).
        fps: frames per second of the video.
        coverage: (F, H, W) uint8, 255 x the covered fraction of each pixel: the true alpha matte.
    """

    arrays: SubjectArrays
    masks: np.ndarray
    fps: float
    coverage: np.ndarray


def walk_config(
    frames: int, width: int = 512, height: int = 384, texture_size: int = 1024, motion: str = "walk"
) -> SynthConfig:
    """The "mono" preset as one continuous walk of ``frames`` frames (no test images).

    The walk keeps the preset's geometry (circle radius, framing) whatever its length: it
    turns once per preset length of frames. ``motion``: another of the generator's motion kinds
    instead of the walk, performed on the spot (``SynthConfig.mono_motion``).
    """
    mono = PRESETS["mono"]
    return replace(
        mono,
        frames=frames,
        test_frames=0,
        novel_views=0,
        walk_laps=frames / mono.frames,
        width=width,
        height=height,
        texture_size=texture_size,
        mono_motion=motion,
    ).validate()


def graded_background(top: tuple[int, int, int], bottom: tuple[int, int, int], width: int, height: int) -> np.ndarray:
    """(H, W, 3) uint8 vertical gradient from colour ``top`` (row 0) to ``bottom`` (last row)."""
    t = np.linspace(0.0, 1.0, height)[:, None, None]
    column = (1 - t) * np.asarray(top, dtype=np.float64) + t * np.asarray(bottom, dtype=np.float64)
    return np.ascontiguousarray(np.broadcast_to(np.round(column), (height, width, 3)).astype(np.uint8))


def composite(view: RenderedView, background: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: the rendered person over ``background`` (H, W, 3) uint8, out = rgb - (1 - a)(1 - b)."""
    rgb = view.rgb.astype(np.float64) / 255
    alpha = view.coverage.astype(np.float64)[..., None] / 255
    out = rgb - (1 - alpha) * (1 - background.astype(np.float64) / 255)
    return np.round(np.clip(out, 0.0, 1.0) * 255).astype(np.uint8)


def render_walk_video(
    config: SynthConfig,
    seed: int,
    out: str | Path,
    background: np.ndarray,
    crf: int = VIDEO_CRF,
    progress: bool = False,
) -> WalkTruth:
    """Render the walk of ``config`` (see :func:`walk_config`) over ``background`` into the H.264 file ``out``.

    Args:
        config: a monocular config without test frames or novel views.
        seed: the generator's seed (subject :data:`SUBJECT_INDEX` of it is filmed).
        out: the video file to write (.mp4).
        background: (H, W, 3) uint8, the config's image size.
        crf: libx264 constant rate factor (0 lossless .. 51 worst).
        progress: show a tqdm bar on stderr.
    """
    import imageio_ffmpeg

    if config.capture != "monocular" or config.test_frames or config.novel_views:
        raise PghmError("walk video: the config must be monocular with no test frames and no novel views")
    if background.shape != (config.height, config.width, 3) or background.dtype != np.uint8:
        raise PghmError(f"walk video: background must be ({config.height}, {config.width}, 3) uint8")
    plan = plan_subject(config, load_body("anny"), seed, SUBJECT_INDEX)
    coverage = np.zeros((config.frames, config.height, config.width), dtype=np.uint8)
    with atomic_path(out, suffix=Path(out).suffix) as temporary:  # a killed render leaves no half video
        writer = imageio_ffmpeg.write_frames(
            str(temporary),
            (config.width, config.height),
            fps=config.fps,
            codec="libx264",
            pix_fmt_out="yuv420p",
            quality=None,
            macro_block_size=1,
            output_params=["-crf", str(crf)],
        )
        writer.send(None)
        try:
            views = render_views(config, plan, list(range(config.frames)))
            for i, view in tqdm(views, total=config.frames, desc="walk video", disable=not progress, file=sys.stderr):
                coverage[i] = view.coverage
                writer.send(np.ascontiguousarray(composite(view, background)))
        finally:
            writer.close()
            release_worker_gl()
    return WalkTruth(plan.arrays, coverage >= round(255 * MASK_COVERAGE), config.fps, coverage)
