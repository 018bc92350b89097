"""The two real motion-capture clips import and play: each BVH file is retargeted onto the
avatar's body and rendered headless by ``render_video`` (the library behind ``pghm render``)
for a few frames spread over the clip.

Truths checked, independent of the importer: the float images the renderer hands to the
writer are finite; the avatar is in the picture (pixels that are not the plain background)
and so is the background; and the silhouette changes from frame to frame, which it can only
do if the body moves, since the camera and the background stay put apart from following the
root horizontally.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SMALL_MODEL
from test_motion_retarget import CLIPS, MOTION_DIR

import pghm.render.job as render_job
from pghm.io.avatar import save_avatar
from pghm.motion.bvh import load_bvh
from pghm.render import RenderJob, render_video
from viewer.demo import development_avatar

FRAMES = 3
SIZE = (64, 64)
BACKGROUND = (1.0, 1.0, 1.0)
BACKGROUND_TOL = 2.0 / 255
"""A pixel further than two 8-bit levels from the background shows the avatar."""
MIN_BODY_FRACTION = 0.03
"""The body, framed to fill most of the height, covers 15-20% of the image; an empty or
collapsed avatar covers (almost) nothing."""
MAX_BODY_FRACTION = 0.5
"""The background must show too: a frame filled by one colour or by garbage is not a body."""
MIN_SILHOUETTE_CHANGE = 0.005
"""Fraction of pixels in exactly one of two consecutive silhouettes: a still body gives 0."""


@pytest.fixture(scope="module")
def avatar_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("clips") / "avatar.pt"
    save_avatar(path, development_avatar(SMALL_MODEL, seed=2))
    return path


def play(avatar_file, clip_path, out, monkeypatch) -> list[np.ndarray]:
    """Render FRAMES frames spread evenly over the clip on the CPU splatter and return the
    float images ``render_video`` passes to the writer (recorded on their way to uint8)."""
    clip = load_bvh(clip_path)
    duration = clip.num_frames * clip.frame_time
    rendered: list[np.ndarray] = []

    def record(rgb: np.ndarray) -> np.ndarray:
        rendered.append(rgb.copy())
        return real_to_uint8(rgb)

    real_to_uint8 = render_job.to_uint8
    monkeypatch.setattr(render_job, "to_uint8", record)
    job = RenderJob(
        avatar=avatar_file,
        out=out,
        motion=str(clip_path),
        size=SIZE,
        fps=FRAMES / duration,
        frames=FRAMES,
        backend="cpu",
        background=BACKGROUND,
    )
    summary = render_video(job, log=lambda _: None)
    assert summary.frames == FRAMES and len(sorted(out.glob("frame_*.png"))) == FRAMES
    return rendered


@pytest.mark.parametrize("clip_name", CLIPS)
def test_real_clip_imports_and_plays(avatar_file, tmp_path, monkeypatch, clip_name):
    frames = play(avatar_file, MOTION_DIR / clip_name, tmp_path / "frames", monkeypatch)
    assert len(frames) == FRAMES
    silhouettes = []
    for k, rgb in enumerate(frames):
        assert rgb.shape == (SIZE[1], SIZE[0], 3) and np.isfinite(rgb).all(), f"frame {k}"
        body = np.abs(rgb - np.array(BACKGROUND)).max(-1) > BACKGROUND_TOL
        assert MIN_BODY_FRACTION < body.mean() < MAX_BODY_FRACTION, (k, body.mean())
        silhouettes.append(body)
    for k in range(FRAMES - 1):
        change = (silhouettes[k] ^ silhouettes[k + 1]).mean()
        assert change > MIN_SILHOUETTE_CHANGE, f"frames {k} and {k + 1}: the body did not move ({change})"
