"""The viewer's documentation images: docs/viewer_screenshot.png and docs/viewer_motion_strip.png.

One command (Xvfb provides the window; re-run after the synthetic avatar changes; the real one's
screenshot, docs/real_avatar_viewer.png, is benchmarks/real_avatar.py's):

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/viewer_shots.py

* viewer_screenshot.png: the default window (1280 x 800) on the synthetic avatar at frame 20
  of the shipped Mixamo walk, settled (the exact frame), the clip list showing the clip.
* viewer_motion_strip.png: window screenshots while the camera orbits the paused walk, then
  while the cached walk plays (reduced internal resolution in the HUD), then the settled
  frame, half size, in a grid.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

from viewer.settings import WINDOW_SIZE
from viewer.viewer import Viewer

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
AVATAR = Path("assets/avatar.pt")
"""Relative to the repository (the path field shows it; no machine's absolute path in the docs)."""
WALK = Path("assets/motion/mixamo_walk_69f.bvh")
IDLE_FRAMES = 20
"""Frames drawn before the screenshot, so that its HUD shows an idle frame's fps, not the settling."""
SCREENSHOT_FRAME = 20
ORBIT_SHOTS = 3
"""Frames of the strip while the camera orbits the paused clip."""
PLAY_SHOTS = 2
"""Frames of the strip while the clip plays (a settled one follows)."""
FRAMES_BETWEEN_SHOTS = 6
ORBIT_PIXELS_PER_FRAME = 12.0
"""Mouse pixels of orbit per frame while the strip plays (4.8 degrees)."""
STRIP_COLUMNS = 3
STRIP_SCALE = 0.5


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DOCS)
    args = parser.parse_args()
    out = args.out.resolve()
    os.chdir(ROOT)
    viewer = Viewer(AVATAR, window_size=WINDOW_SIZE)
    viewer.setup()
    try:
        screenshot = out / "viewer_screenshot.png"
        settled_screenshot(viewer, WALK, SCREENSHOT_FRAME, screenshot)
        print(f"wrote {screenshot}")

        shots = []
        for _ in range(ORBIT_SHOTS):  # orbiting the paused frame
            for _ in range(FRAMES_BETWEEN_SHOTS):
                viewer.orbit(ORBIT_PIXELS_PER_FRAME, 0.0)
                viewer.frame()
            viewer.orbit(ORBIT_PIXELS_PER_FRAME, 0.0)
            shots.append(capture(viewer))
        viewer.settle()
        viewer.pipeline.worker.wait_background_idle()  # the clip's colour for this view
        viewer.set_playing(True)
        for _ in range(PLAY_SHOTS):  # playing from the cache
            for _ in range(FRAMES_BETWEEN_SHOTS):
                viewer.frame()
            shots.append(capture(viewer))
        viewer.set_playing(False)
        time.sleep(viewer.resolution.settings.settle_seconds)
        viewer.settle()
        shots.append(capture(viewer))
        strip = out / "viewer_motion_strip.png"
        save_grid(shots, strip)
        print(f"wrote {strip}")
    finally:
        viewer.teardown()


def settled_screenshot(viewer: Viewer, motion: Path, frame: int, path: Path) -> None:
    """The whole window written to ``path`` at ``frame`` of ``motion``, settled and its clip cached."""
    viewer.open_motion(str(motion))
    viewer.scrub_to(frame)
    viewer.settle()
    viewer.pipeline.worker.wait_background_idle()  # the clip is cached: the HUD shows its fill
    for _ in range(IDLE_FRAMES):
        viewer.frame()
    viewer.screenshot(path, include_ui=True)
    viewer.frame()
    viewer.message = None  # "saved <absolute path>" would show in the next screenshot's panel


def capture(viewer: Viewer) -> np.ndarray:
    """The whole window (UI included) as the next frame draws it."""
    with tempfile.TemporaryDirectory() as folder:
        viewer.screenshot(Path(folder) / "shot.png", include_ui=True)
        viewer.frame()
    viewer.message = None  # the panel's "saved ..." line would show the temporary path next time
    return viewer.last_screenshot


def save_grid(images: list[np.ndarray], path: Path) -> None:
    """``images`` scaled by STRIP_SCALE in rows of STRIP_COLUMNS, 4-pixel gaps."""
    scaled = [
        Image.fromarray(image).resize((round(image.shape[1] * STRIP_SCALE), round(image.shape[0] * STRIP_SCALE)))
        for image in images
    ]
    width, height = scaled[0].size
    gap = 4
    rows = -(-len(scaled) // STRIP_COLUMNS)
    size = (STRIP_COLUMNS * width + (STRIP_COLUMNS - 1) * gap, rows * height + (rows - 1) * gap)
    grid = Image.new("RGB", size, "white")
    for k, image in enumerate(scaled):
        grid.paste(image, ((k % STRIP_COLUMNS) * (width + gap), (k // STRIP_COLUMNS) * (height + gap)))
    grid.save(path, optimize=True)


if __name__ == "__main__":
    main()
