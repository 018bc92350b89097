"""Camera set-ups: multi-view capture rings and a monocular (hand-held-like) camera.

All cameras follow the project's model (:mod:`pghm.splat.camera`): pinhole, OpenCV axes
(x right, y down, z forward), ``world_to_camera`` = [R T; 0 1], K = [[fx, 0, cx], [0, fy,
cy], [0, 0, 1]], square pixels (fx = fy).
"""

from __future__ import annotations

import numpy as np

UP = np.array([0.0, 1.0, 0.0])


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = UP) -> np.ndarray:
    """(4, 4) world_to_camera of a camera at ``eye`` looking at ``target``, ``up`` towards the image top.

    Rows of R are the camera axes in world coordinates: right = forward x up, down =
    forward x right, forward = (target - eye) / |target - eye|; T = -R eye.
    """
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    matrix = np.eye(4)
    matrix[:3, :3] = np.stack([right, down, forward])
    matrix[:3, 3] = -matrix[:3, :3] @ eye
    return matrix


def intrinsics(focal: float, width: int, height: int, principal_offset: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """(3, 3) K with fx = fy = ``focal`` and the principal point at the image centre plus an offset (pixels)."""
    return np.array(
        [
            [focal, 0.0, width / 2 + principal_offset[0]],
            [0.0, focal, height / 2 + principal_offset[1]],
            [0.0, 0.0, 1.0],
        ]
    )


def framing_focal(distance: float, extent: float, size: int, fill: float) -> float:
    """Focal length (pixels) at which ``extent`` metres at ``distance`` span ``fill`` x ``size`` pixels."""
    return fill * size * distance / extent


def ring_cameras(
    rng: np.random.Generator,
    views: int,
    target: np.ndarray,
    span: float,
    width: int,
    height: int,
    distance_range: tuple[float, float],
    elevation_range_deg: tuple[float, float],
    fill: float,
) -> tuple[np.ndarray, np.ndarray]:
    """A capture ring around ``target``: cameras spread in azimuth, at varied heights and distances.

    Azimuths are evenly spaced from a random start, each jittered by up to a quarter of
    the spacing; elevations (degrees above the target) and distances are uniform in
    their ranges. Focal lengths make ``span`` metres at the target's distance fill ``fill``
    of the image height; principal points sit within 2 % of the centre.

    Returns:
        K: (views, 3, 3), world_to_camera: (views, 4, 4).
    """
    spacing = 2 * np.pi / views
    start = rng.uniform(0, 2 * np.pi)
    Ks, Es = [], []
    for view in range(views):
        azimuth = start + view * spacing + rng.uniform(-0.25, 0.25) * spacing
        elevation = np.radians(rng.uniform(*elevation_range_deg))
        distance = rng.uniform(*distance_range)
        eye = target + distance * np.array(
            [np.sin(azimuth) * np.cos(elevation), np.sin(elevation), np.cos(azimuth) * np.cos(elevation)]
        )
        focal = framing_focal(distance, span, height, fill)
        offset = (rng.uniform(-0.02, 0.02) * width, rng.uniform(-0.02, 0.02) * height)
        Ks.append(intrinsics(focal, width, height, offset))
        Es.append(look_at(eye, target))
    return np.stack(Ks), np.stack(Es)


def monocular_cameras(
    rng: np.random.Generator,
    frames: int,
    centre: np.ndarray,
    focal: float,
    width: int,
    height: int,
    distance: float,
    elevation_deg: float,
    drift_deg: float,
) -> tuple[np.ndarray, np.ndarray]:
    """One slowly moving camera filming a scene around ``centre`` for ``frames`` frames.

    The camera starts in front of the scene at a random azimuth within +-20 degrees of
    +z and drifts sideways along a circle by ``drift_deg`` in total (a slow pan, as when
    filming by hand), always looking at ``centre``, with fx = fy = ``focal`` pixels.

    Returns:
        K: (frames, 3, 3), world_to_camera: (frames, 4, 4).
    """
    start = np.radians(rng.uniform(-20, 20))
    drift = np.radians(drift_deg) * rng.choice([-1.0, 1.0])
    elevation = np.radians(elevation_deg)
    K = intrinsics(focal, width, height)
    Es = []
    for frame in range(frames):
        azimuth = start + drift * frame / max(frames - 1, 1)
        eye = centre + distance * np.array(
            [np.sin(azimuth) * np.cos(elevation), np.sin(elevation), np.cos(azimuth) * np.cos(elevation)]
        )
        Es.append(look_at(eye, centre))
    return np.repeat(K[None], frames, axis=0), np.stack(Es)
