"""The viewer's orbit camera: a target, two angles, a distance and a field of view.

Mouse gestures map to :meth:`OrbitController.orbit` (left drag), :meth:`pan` (right drag)
and :meth:`zoom` (wheel); the views of :data:`SNAP_VIEWS` and :meth:`reset` restore angles.
The camera itself is built by :func:`pghm.render.framing.orbit_camera` (shared with
``pghm render``), in OpenCV axes like every pghm camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pghm.errors import PghmError
from pghm.render import DEFAULT_FOV_Y, Framing, orbit_camera
from pghm.splat import Camera

DEGREES_PER_PIXEL = 0.4
"""Orbit speed: a 450-pixel drag turns the camera half way round."""
ZOOM_PER_STEP = 0.9
"""Each wheel step multiplies the distance by this (towards the target)."""
PITCH_LIMIT = 90.0
"""Pitch stays within +-this many degrees (the poles are the top and bottom views)."""
MIN_DISTANCE, MAX_DISTANCE = 0.05, 100.0
"""Zoom range, metres."""
FOV_RANGE = (10.0, 120.0)
"""Accepted vertical fields of view, degrees."""

SNAP_VIEWS: dict[str, tuple[float, float]] = {
    "front": (0.0, 0.0),
    "left": (90.0, 0.0),
    "back": (180.0, 0.0),
    "right": (-90.0, 0.0),
    "top": (0.0, 90.0),
}
"""(yaw, pitch) in degrees of the snap buttons; yaw 0 faces the body's front (+z)."""


@dataclass(frozen=True)
class OrbitView:
    """The orbit state as a value (hashable): what the view-dependent colour of a frame was made for.

    The camera of a frame is this view with its target shifted by ``offset`` (the root's
    horizontal motion when following the body).
    """

    target: tuple[float, float, float]
    yaw: float
    pitch: float
    distance: float
    fov_y: float

    def camera(self, offset: np.ndarray, width: int, height: int) -> Camera:
        """The pinhole camera for a W x H image, target moved by ``offset`` (3,)."""
        target = np.asarray(self.target, dtype=np.float64) + offset
        return orbit_camera(target, self.yaw, self.pitch, self.distance, self.fov_y, width, height)

    def centre(self, offset: np.ndarray) -> np.ndarray:
        """(3,) float32 camera centre, target moved by ``offset``."""
        return self.camera(offset, 2, 2).centre.numpy().astype(np.float32)

    def degrees_to(self, other: OrbitView) -> float:
        """Angle between the two viewing directions (from the target to the camera), degrees."""
        a, b = self._direction(), other._direction()
        return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))

    def _direction(self) -> np.ndarray:
        yaw, pitch = math.radians(self.yaw), math.radians(self.pitch)
        return np.array([math.cos(pitch) * math.sin(yaw), math.sin(pitch), math.cos(pitch) * math.cos(yaw)])


@dataclass
class OrbitController:
    """Camera state and the gestures that change it.

    Attributes:
        home: the framing ``reset`` returns to (target and distance).
        target: (3,) point looked at, metres.
        yaw: degrees around world y, 0 on the body's front (+z), 90 on its left (+x).
        pitch: degrees above the horizontal.
        distance: metres from the target.
        fov_y: vertical field of view, degrees.
        offset: (3,) added to the target, e.g. the root's horizontal motion when following it.
    """

    home: Framing
    target: np.ndarray = field(init=False)
    yaw: float = 0.0
    pitch: float = 0.0
    distance: float = field(init=False)
    fov_y: float = DEFAULT_FOV_Y
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.target = np.asarray(self.home.target, dtype=np.float64).copy()
        self.distance = self.home.distance

    def orbit(self, dx_pixels: float, dy_pixels: float) -> None:
        """Turn around the target: dragging right moves the camera left round the body, dragging up lowers it."""
        self.yaw = (self.yaw - dx_pixels * DEGREES_PER_PIXEL + 180.0) % 360.0 - 180.0
        self.pitch = float(np.clip(self.pitch + dy_pixels * DEGREES_PER_PIXEL, -PITCH_LIMIT, PITCH_LIMIT))

    def pan(self, dx_pixels: float, dy_pixels: float, viewport_height: int) -> None:
        """Move the target in the image plane so that the scene follows the cursor.

        At the target's depth one pixel spans 2 d tan(fov / 2) / H metres.
        """
        metres_per_pixel = 2.0 * self.distance * math.tan(math.radians(self.fov_y) / 2) / max(viewport_height, 1)
        rotation = self._rotation()
        right, down = rotation[0], rotation[1]
        self.target = self.target - (dx_pixels * right + dy_pixels * down) * metres_per_pixel

    def zoom(self, steps: float) -> None:
        """Wheel steps: positive moves the camera towards the target."""
        self.distance = float(np.clip(self.distance * ZOOM_PER_STEP**steps, MIN_DISTANCE, MAX_DISTANCE))

    def set_fov(self, degrees: float) -> None:
        if not FOV_RANGE[0] <= degrees <= FOV_RANGE[1]:
            raise PghmError(f"field of view must be in [{FOV_RANGE[0]}, {FOV_RANGE[1]}] degrees, got {degrees}")
        self.fov_y = float(degrees)

    def snap(self, view: str) -> None:
        """Look from one of :data:`SNAP_VIEWS`, keeping target and distance."""
        if view not in SNAP_VIEWS:
            raise PghmError(f"unknown view {view!r}, expected one of {', '.join(SNAP_VIEWS)}")
        self.yaw, self.pitch = SNAP_VIEWS[view]

    def reset(self) -> None:
        """The home framing from the front, default field of view."""
        self.target = np.asarray(self.home.target, dtype=np.float64).copy()
        self.distance = self.home.distance
        self.yaw, self.pitch, self.fov_y = 0.0, 0.0, DEFAULT_FOV_Y

    def camera(self, width: int, height: int) -> Camera:
        """The pinhole camera of the current state for a W x H image."""
        return self.view().camera(self.offset, width, height)

    def view(self) -> OrbitView:
        """The current state (without ``offset``) as a value."""
        target = tuple(float(v) for v in self.target)
        return OrbitView(target, float(self.yaw), float(self.pitch), float(self.distance), float(self.fov_y))

    def _rotation(self) -> np.ndarray:
        """(3, 3) world-to-camera rotation: rows are the camera's right, down and forward axes."""
        return self.camera(2, 2).world_to_camera[:3, :3].double().numpy()
