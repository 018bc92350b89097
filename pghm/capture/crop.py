"""The region the person occupies over a video, and the intrinsics of images cropped to it.

A static camera filming a person in the middle of a room sees mostly room: training an
avatar on those frames spends its pixels on background. The subject's images are cut to
one fixed rectangle for the whole video, the union of the person's per-frame boxes plus a
margin, so the camera stays one static pinhole camera with a shifted principal point.

Pixel coordinates follow docs/data.md: pixel (row i, column j) covers [j, j + 1) x [i, i + 1),
its centre at (j + 0.5, i + 0.5). Boxes are (x0, y0, x1, y1) in those continuous coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Region:
    """An integer pixel rectangle of the upright video frame: columns x .. x + width - 1, rows y .. y + height - 1."""

    x: int
    y: int
    width: int
    height: int

    @classmethod
    def full(cls, width: int, height: int) -> Region:
        return cls(0, 0, width, height)

    def to_json(self) -> dict:
        return {"x": self.x, "y": self.y, "width": self.width, "height": self.height}


def person_region(boxes: np.ndarray, width: int, height: int, margin: float) -> Region:
    """The rectangle of a W x H frame that holds every box, grown by ``margin`` on each side.

    The union [min x0, max x1] x [min y0, max y1] grows by ``margin`` x its longest side on
    every side, is rounded outwards to whole pixels and clipped to the frame.

    Args:
        boxes: (F, 4) person boxes (x0, y0, x1, y1), pixels of the W x H frame.
        width: W.
        height: H.
        margin: fraction of the union's longest side added on each side.
    """
    x0, y0 = boxes[:, 0].min(), boxes[:, 1].min()
    x1, y1 = boxes[:, 2].max(), boxes[:, 3].max()
    pad = margin * max(x1 - x0, y1 - y0)
    left, top = max(0, math.floor(x0 - pad)), max(0, math.floor(y0 - pad))
    right, bottom = min(width, math.ceil(x1 + pad)), min(height, math.ceil(y1 + pad))
    return Region(left, top, max(1, right - left), max(1, bottom - top))


def crop_intrinsics(K: np.ndarray, region: Region, out_size: tuple[int, int]) -> np.ndarray:
    """(3, 3) intrinsics of the images made by cropping ``region`` and resizing it to ``out_size``.

    A point at (u, v) in the full frame is at ((u - x) sx, (v - y) sy) in the output, with
    sx = W' / width and sy = H' / height (continuous coordinates, so pixel centres map to
    pixel centres under area resampling). Hence fx' = sx fx, cx' = sx (cx - x), and likewise
    in y.

    Args:
        K: (3, 3) intrinsics in pixels of the full frame.
        region: the crop.
        out_size: (H', W') of the output images.
    """
    sx, sy = out_size[1] / region.width, out_size[0] / region.height
    scale_shift = np.array([[sx, 0.0, -sx * region.x], [0.0, sy, -sy * region.y], [0.0, 0.0, 1.0]])
    return scale_shift @ np.asarray(K, dtype=np.float64)


def to_region(points: np.ndarray, region: Region, out_size: tuple[int, int]) -> np.ndarray:
    """(..., 2) pixel coordinates of the full frame -> the same points in the cropped, resized images."""
    scale = np.array([out_size[1] / region.width, out_size[0] / region.height])
    return (points - np.array([region.x, region.y])) * scale


def frame_box(region: Region, width: int, height: int, out_size: tuple[int, int]) -> np.ndarray:
    """(4,) float32 x0, y0, x1, y1: the whole W x H frame's extent in the pixels of the images cut from ``region``."""
    corners = to_region(np.array([[0.0, 0.0], [float(width), float(height)]]), region, out_size)
    return corners.reshape(4).astype(np.float32)


def from_region(points: np.ndarray, region: Region, out_size: tuple[int, int]) -> np.ndarray:
    """Inverse of :func:`to_region`: (..., 2) pixels of the cropped images -> pixels of the full frame."""
    scale = np.array([region.width / out_size[1], region.height / out_size[0]])
    return points * scale + np.array([region.x, region.y])


FRAME_EDGES = ("left", "top", "right", "bottom")


def frame_edges(region: Region, width: int, height: int) -> list[str]:
    """The edges of the W x H frame that ``region`` reaches (:data:`FRAME_EDGES` names, in that order)."""
    reached = (region.x == 0, region.y == 0, region.x + region.width == width, region.y + region.height == height)
    return [edge for edge, on in zip(FRAME_EDGES, reached) if on]


def edge_pixels(masks: np.ndarray, edge: str) -> np.ndarray:
    """(F,) the fraction of the outermost row or column on ``edge`` that each (F, H, W) mask covers."""
    line = {"left": masks[:, :, 0], "top": masks[:, 0, :], "right": masks[:, :, -1], "bottom": masks[:, -1, :]}[edge]
    return np.asarray(line).mean(axis=1)
