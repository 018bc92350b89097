"""Cameras that frame a body: an orbit around a target, and the target and distance that fill the image.

:func:`orbit_camera` is shared by ``pghm render`` and the viewer's camera
(:mod:`viewer.camera`); :func:`frame_points` gives both their default framing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pghm.splat import Camera

DEFAULT_FOV_Y = 40.0
"""Vertical field of view, degrees, of the default cameras."""
BODY_FILL = 0.85
"""The default framing makes the body's bounding box fill this fraction of the image height (or width)."""
POLE_TOLERANCE = 1e-6
"""|cos(pitch)| below which :func:`orbit_camera` treats the camera as straight above or below."""


@dataclass(frozen=True)
class Framing:
    """Where a camera looks and from how far to frame a set of points.

    Attributes:
        target: (3,) the bounding box centre, world metres.
        distance: camera distance from the target, metres.
    """

    target: tuple[float, float, float]
    distance: float


def frame_points(points: np.ndarray, fov_y_degrees: float = DEFAULT_FOV_Y, aspect: float = 1.0) -> Framing:
    """The framing of points (N, 3) seen from the front (+z), filling BODY_FILL of the image.

    The box's half-height h and half-width w must fit tan(fov_y / 2) d BODY_FILL and that
    times ``aspect`` (W / H) at distance d from the box's front face.
    """
    low, high = points.min(axis=0), points.max(axis=0)
    centre = (low + high) / 2
    half = (high - low) / 2
    tangent = math.tan(math.radians(fov_y_degrees) / 2) * BODY_FILL
    distance = max(half[1] / tangent, half[0] / (tangent * aspect)) + half[2]
    return Framing(target=tuple(float(c) for c in centre), distance=float(distance))


def floor_shift(root: np.ndarray, rest_root: np.ndarray) -> np.ndarray:
    """(3,) the root's move from ``rest_root`` across the floor (x and z; y kept at 0): what a camera
    that follows the body adds to its target, so it keeps its height as the body bobs."""
    shift = np.asarray(root, dtype=np.float64) - np.asarray(rest_root, dtype=np.float64)
    return np.array([shift[0], 0.0, shift[2]])


def orbit_camera(
    target: tuple[float, float, float] | np.ndarray,
    yaw_degrees: float,
    pitch_degrees: float,
    distance: float,
    fov_y_degrees: float,
    width: int,
    height: int,
) -> Camera:
    """A camera ``distance`` from ``target`` looking at it, world y up on screen.

    Yaw 0 puts the camera on the +z side (the body's front, pghm.body.pose), yaw 90 on +x
    (the body's left); pitch > 0 lifts it above the target. At |pitch| = 90 the up vector
    turns to -z / +z so that the view stays defined (top and bottom views).
    """
    yaw, pitch = math.radians(yaw_degrees), math.radians(pitch_degrees)
    direction = np.array([math.cos(pitch) * math.sin(yaw), math.sin(pitch), math.cos(pitch) * math.cos(yaw)])
    eye = np.asarray(target, dtype=np.float64) + distance * direction
    up = (0.0, 1.0, 0.0)
    if abs(math.cos(pitch)) < POLE_TOLERANCE:
        # Straight above (below) the target world y is the view axis; the limit of its
        # projection as the pitch approaches the pole is away from (towards) where the
        # camera came from horizontally.
        sign = math.copysign(1.0, pitch)
        up = (-sign * math.sin(yaw), 0.0, -sign * math.cos(yaw))
    return Camera.look_at(eye, target, up=up, fov_y_degrees=fov_y_degrees, width=width, height=height)
