"""Training images cropped to the person: the same loss for a fraction of the pixels.

A capture's frames are mostly background: the dribbling player covers about a third of his
390 x 512 frames. Every pixel outside the person costs compositing, SSIM, the silhouette and the
splatter's per-pixel work, and contributes nothing once the render there is the background. So
each training image is cut to a box of one size per subject, w x h (the largest mask bounding
box, plus :data:`CROP_MARGIN` on every side, within the frame), placed around that image's
mask and kept inside the frame. The camera follows exactly: a crop at (x0, y0) is the same
pinhole with its principal point moved,

    cx' = cx - x0,   cy' = cy - y0,

so pixel (i, j) of the crop's render is pixel (i + y0, j + x0) of the full render.

The loss is kept the full frame's. Outside the box the target is the background and so is the
render wherever no Gaussian reaches (the margin holds the outline's soft edge and SSIM's windows), so the
per-pixel means (L1, silhouette) of the full frame are the crop's times its share of the pixels,
and SSIM's mean over its valid windows (1 - SSIM = 0 over identical flat regions) the crop's
times its share of the windows:

    s_pixels = w h / (W H),   s_windows = (w - 10)(h - 10) / ((W - 10)(H - 10))   (11-tap window).

LPIPS, whose features see further, is scaled by s_pixels: close, not exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from pghm.splat import Camera
from pghm.train.losses import SSIM_WINDOW

CROP_MARGIN = 16
"""Pixels kept around the mask's bounding box on every side. At least SSIM_WINDOW - 1 (10): the
frame's windows that see the person, centred up to 5 pixels from it, must lie 5 pixels inside the
crop to be the crop's; the rest holds the outline's soft edge."""


@dataclass(frozen=True)
class Crop:
    """A w x h box at (x0, y0) of a W x H frame."""

    x0: int
    y0: int
    width: int
    height: int
    frame_width: int
    frame_height: int

    def image(self, array: np.ndarray) -> np.ndarray:
        """The box of an (H, W, ...) array."""
        return array[self.y0 : self.y0 + self.height, self.x0 : self.x0 + self.width]

    def camera(self, camera: Camera) -> Camera:
        """The camera whose image is this box of ``camera``'s: the principal point moved by (-x0, -y0)."""
        return Camera(
            fx=camera.fx,
            fy=camera.fy,
            cx=camera.cx - self.x0,
            cy=camera.cy - self.y0,
            width=self.width,
            height=self.height,
            world_to_camera=camera.world_to_camera,
        )

    def area_shares(self) -> tuple[float, float]:
        """(s_pixels, s_windows): the box's share of the frame's pixels and of its SSIM windows."""
        reach = SSIM_WINDOW - 1
        pixels = self.width * self.height / (self.frame_width * self.frame_height)
        frame_windows = (self.frame_width - reach) * (self.frame_height - reach)
        windows = (self.width - reach) * (self.height - reach) / frame_windows
        return pixels, windows


def mask_box(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1), end-exclusive, of the pixels of an (H, W) matte above 0; None if there are none."""
    rows, columns = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if len(rows) == 0:
        return None
    return int(columns[0]), int(rows[0]), int(columns[-1]) + 1, int(rows[-1]) + 1


def crop_size(boxes: list[tuple[int, int, int, int]], width: int, height: int, margin: int) -> tuple[int, int]:
    """(w, h): the largest box plus ``margin`` on every side, at most the frame (W, H), at least
    SSIM's window."""
    w = max((x1 - x0 for x0, _, x1, _ in boxes), default=width) + 2 * margin
    h = max((y1 - y0 for _, y0, _, y1 in boxes), default=height) + 2 * margin
    return min(width, max(w, SSIM_WINDOW)), min(height, max(h, SSIM_WINDOW))


def place(box: tuple[int, int, int, int] | None, size: tuple[int, int], width: int, height: int) -> Crop:
    """The ``size`` crop centred on ``box`` (the frame's centre for none), moved inside the W x H frame."""
    w, h = size
    x0, y0, x1, y1 = box if box is not None else (0, 0, width, height)
    left = min(max((x0 + x1 - w) // 2, 0), width - w)
    top = min(max((y0 + y1 - h) // 2, 0), height - h)
    return Crop(left, top, w, h, width, height)


def area_tensor(crops: list[Crop | None]) -> torch.Tensor:
    """(B, 2) float32 (s_pixels, s_windows) of each image; (1, 1) for an uncropped one."""
    return torch.tensor([crop.area_shares() if crop else (1.0, 1.0) for crop in crops], dtype=torch.float32)
