"""Brute-force geometry written independently of pghm, for tests to compare against."""

from __future__ import annotations

import numpy as np
import torch


def closest_point_on_triangles(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Closest points (K, 3) of triangles (a, b, c) to points p, all (K, 3).

    Ericson, Real-Time Collision Detection, 5.1.5: classify p against the Voronoi regions
    of the triangle's vertices, edges and face.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    v = vb / denom
    w = vc / denom
    result = a + ab * v[:, None] + ac * w[:, None]  # face region

    def where(mask, value):
        nonlocal result
        result = torch.where(mask[:, None], value, result)

    # Edge regions (applied before vertex regions, which take precedence).
    t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    where((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc[:, None])
    where((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / (d2 - d6))[:, None])
    where((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / (d1 - d3))[:, None])
    where((d6 >= 0) & (d5 <= d6), c)
    where((d3 >= 0) & (d4 <= d3), b)
    where((d1 <= 0) & (d2 <= 0), a)
    return result


def distance_to_mesh(
    points: torch.Tensor, vertices: torch.Tensor, faces: torch.Tensor, voxel: float = 0.01
) -> torch.Tensor:
    """(N,) distance from each point to the nearest triangle whose bounding box holds the point's voxel.

    Triangles are binned by every voxel (edge ``voxel`` metres) their bounding box touches;
    a point is compared with every triangle in its voxel. Exact for points on or within
    ``voxel`` of the surface, an upper bound (possibly inf) elsewhere; independent of any
    of pghm's UV bookkeeping.
    """
    points, vertices = points.double(), vertices.double()
    tri = vertices[faces]  # (F, 3, 3)
    # Boxes grown by a micrometre, for points a rounding error off a triangle on a voxel face.
    lo = torch.floor((tri.min(1).values - 1e-6) / voxel).long()
    hi = torch.floor((tri.max(1).values + 1e-6) / voxel).long()
    span = hi - lo + 1
    count = span.prod(-1)
    face_id = torch.repeat_interleave(torch.arange(len(faces)), count)
    local = torch.arange(int(count.sum())) - torch.repeat_interleave(torch.cumsum(count, 0) - count, count)
    sy, sz = span[face_id, 1], span[face_id, 2]
    cell = lo[face_id] + torch.stack([local // (sy * sz), (local // sz) % sy, local % sz], -1)

    def key(c: torch.Tensor) -> torch.Tensor:
        return ((c[:, 0] + 4096) * 8192 + (c[:, 1] + 4096)) * 8192 + (c[:, 2] + 4096)

    cell_key = key(cell)
    order = torch.argsort(cell_key)
    cell_key, face_id = cell_key[order], face_id[order]
    point_key = key(torch.floor(points / voxel).long())
    first = torch.searchsorted(cell_key, point_key)
    last = torch.searchsorted(cell_key, point_key, right=True)
    n = last - first
    point_id = torch.repeat_interleave(torch.arange(len(points)), n)
    pair = torch.arange(int(n.sum())) - torch.repeat_interleave(torch.cumsum(n, 0) - n, n)
    cand = face_id[first[point_id] + pair]
    p = points[point_id]
    t = tri[cand]
    dist = (closest_point_on_triangles(p, t[:, 0], t[:, 1], t[:, 2]) - p).norm(dim=-1)
    best = torch.full((len(points),), float("inf"), dtype=torch.float64)
    return best.scatter_reduce(0, point_id, dist, reduce="amin")


def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """3x3 rotation of an axis-angle vector, float64, by the textbook formula."""
    theta = np.linalg.norm(rotvec)
    if theta < 1e-15:
        return np.eye(3)
    k = rotvec / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx
