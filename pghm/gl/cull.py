"""Back-face culling of surface Gaussians: which ones face a camera (an approximation of the image).

A Gaussian of a surface avatar sits on the body with a posed unit normal n. Seen from a
camera centred at c, its direction to the camera is v = (c - mu) / |c - mu|; it faces the
camera when n . v > 0. Its blob reaches past the silhouette, and a camera that has moved
since the test sees a little further round, so the cull keeps a margin of ``degrees``
beyond the silhouette:

    kept  <=>  n . v >= -sin(degrees)

i.e. the normal is less than 90 + ``degrees`` degrees from v. On a closed opaque surface
the culled Gaussians lie behind the kept ones, so the image hardly changes while the
sprite pass (vertex-bound on a software rasteriser) draws fewer of them
(docs/viewer.md measures both).
"""

from __future__ import annotations

import math

import numpy as np


def camera_centre(world_to_camera: np.ndarray) -> np.ndarray:
    """(3,) float64 centre c = -R^T T of a camera with world_to_camera (4, 4) = [[R, T], [0, 1]]."""
    w2c = np.asarray(world_to_camera, dtype=np.float64)
    return -w2c[:3, :3].T @ w2c[:3, 3]


def facing(means: np.ndarray, normals: np.ndarray, centre: np.ndarray, degrees: float) -> np.ndarray:
    """(N,) bool: n . (c - mu) >= -sin(``degrees``) |c - mu| for means, normals (N, 3), centre c (3,).

    The inequality times |c - mu| avoids the division (a Gaussian at the centre itself is kept).
    """
    cx, cy, cz = np.asarray(centre, dtype=np.float64)
    mx, my, mz = (column.astype(np.float64) for column in np.asarray(means).T)  # 1-D: numpy is slow on rows of 3
    nx, ny, nz = (column.astype(np.float64) for column in np.asarray(normals).T)
    vx, vy, vz = cx - mx, cy - my, cz - mz
    along = nx * vx + ny * vy + nz * vz
    return along >= -math.sin(math.radians(degrees)) * np.sqrt(vx * vx + vy * vy + vz * vz)
