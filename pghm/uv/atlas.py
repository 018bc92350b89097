"""The UV atlas: which surface point each texel of an L x L map carries.

Texel (row i, column j) has its centre at u = (j + 0.5) / L, v = 1 - (i + 0.5) / L (v up,
rows down, as images). Each valid texel becomes one Gaussian, at the surface point with
the texel's barycentric coordinates in its triangle.

Rasterisation rules, chosen so that the result is deterministic and watertight:

1. Corners are snapped to a fixed-point grid of ``SUBTEXELS`` steps per texel and the edge
   functions are evaluated exactly in int64, so a texel centre on an edge shared by two
   triangles is decided identically for both.
2. Top-left rule: a centre exactly on an edge belongs to the triangle for which that edge
   is a "top" or "left" edge; a shared edge is one for exactly one of its two triangles,
   so no texel inside a chart is lost or assigned twice.
3. Overlapping UV triangles (mirrored islands) cannot give a texel two owners: the lowest
   face index keeps it. ``overlap_count`` reports how often that happened.
4. Dilation: an uncovered texel whose centre lies within half a texel diagonal of a
   triangle (its cell touches the triangle) is given to the nearest such triangle, at the
   closest surface point (clamped barycentrics). This keeps islands thinner than a texel
   (fingers, ears at L = 32) from vanishing; the points stay exactly on the surface.

The rasterisation depends only on the UV layout, not on the body shape, so it is cached
on disk per body topology and resolution (``$PGHM_CACHE_DIR`` or ``~/.cache/pghm``);
shape-dependent quantities (:mod:`pghm.uv.maps`) are blends computed in a millisecond.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pghm.errors import PghmError
from pghm.io.atomic import atomic_write_bytes
from pghm.io.read_errors import NPZ_READ_ERRORS

SUBTEXELS = 256
"""Fixed-point steps per texel for the exact edge tests (8 bits of sub-texel precision)."""

DILATION_RADIUS = 0.5 * np.sqrt(2.0)
"""Half a texel diagonal, in texels: a texel whose centre is this close touches the triangle."""

MIN_RESOLUTION, MAX_RESOLUTION = 32, 1024
ATLAS_FORMAT = 1
"""Bumped whenever the rasterisation rules change, so old cache files are not reused."""


@dataclass(frozen=True)
class UVAtlas:
    """The valid texels of an L x L UV map.

    Attributes:
        resolution: L.
        texel_rc: (N, 2) long (row, column) of each valid texel, in row-major order.
        face: (N,) long triangle of each texel.
        barycentric: (N, 3) float32 barycentric coordinates in that triangle (sum 1, >= 0).
        chart: (N,) long UV island of the triangle.
        dilated: (N,) bool, True for texels added by dilation (centre outside the island).
        overlap_count: texels claimed by more than one triangle (kept by the lowest index).
    """

    resolution: int
    texel_rc: Tensor
    face: Tensor
    barycentric: Tensor
    chart: Tensor
    dilated: Tensor
    overlap_count: int

    @property
    def num_texels(self) -> int:
        return self.face.shape[0]

    @property
    def flat_index(self) -> Tensor:
        """(N,) long index of each texel into a flattened L*L map."""
        return self.texel_rc[:, 0] * self.resolution + self.texel_rc[:, 1]

    @property
    def mask(self) -> Tensor:
        """(L, L) bool validity mask."""
        mask = torch.zeros(self.resolution * self.resolution, dtype=torch.bool)
        mask[self.flat_index] = True
        return mask.view(self.resolution, self.resolution)

    def texel_uv(self) -> Tensor:
        """(N, 2) (u, v) of each texel centre."""
        rc = self.texel_rc.to(torch.float64)
        u = (rc[:, 1] + 0.5) / self.resolution
        v = 1.0 - (rc[:, 0] + 0.5) / self.resolution
        return torch.stack([u, v], dim=-1)


def check_resolution(resolution: int) -> int:
    if (
        not isinstance(resolution, int)
        or resolution < MIN_RESOLUTION
        or resolution > MAX_RESOLUTION
        or resolution & (resolution - 1)
    ):
        raise PghmError(
            f"UV resolution must be a power of two from {MIN_RESOLUTION} to {MAX_RESOLUTION}, got {resolution}"
        )
    return resolution


def uv_charts(uv_faces: np.ndarray) -> np.ndarray:
    """(F,) island id of each triangle: triangles sharing a UV vertex are in one island.

    Ids are numbered by each island's lowest triangle index, so they are deterministic.
    """
    num_uv = int(uv_faces.max()) + 1
    parent = np.arange(num_uv)

    def find(x: int) -> int:
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            parent[x], x = root, parent[x]
        return root

    for a, b, c in uv_faces:
        ra, rb, rc = find(a), find(b), find(c)
        low = min(ra, rb, rc)
        parent[ra] = parent[rb] = parent[rc] = low
    roots = np.array([find(int(a)) for a in uv_faces[:, 0]])
    _, chart = np.unique(roots, return_inverse=True)
    # Renumber islands in order of their first triangle.
    first = np.full(chart.max() + 1, len(chart))
    np.minimum.at(first, chart, np.arange(len(chart)))
    return np.argsort(np.argsort(first))[chart]


def _candidates(lo: np.ndarray, hi: np.ndarray, resolution: int) -> tuple[np.ndarray, ...]:
    """Texels whose centres fall in each triangle's box [lo, hi] (texel units, x then y).

    Returns (triangle, row, col) arrays, one entry per (triangle, texel) candidate.
    """
    j0 = np.clip(np.ceil(lo[:, 0] - 0.5), 0, resolution - 1).astype(np.int64)
    j1 = np.clip(np.floor(hi[:, 0] - 0.5), 0, resolution - 1).astype(np.int64)
    i0 = np.clip(np.ceil(lo[:, 1] - 0.5), 0, resolution - 1).astype(np.int64)
    i1 = np.clip(np.floor(hi[:, 1] - 0.5), 0, resolution - 1).astype(np.int64)
    width = np.maximum(j1 - j0 + 1, 0)
    height = np.maximum(i1 - i0 + 1, 0)
    # Boxes entirely outside the map clip to one texel; drop them.
    outside = (hi[:, 0] < 0.5) | (lo[:, 0] > resolution - 0.5) | (hi[:, 1] < 0.5) | (lo[:, 1] > resolution - 0.5)
    count = np.where(outside, 0, width * height)
    tri = np.repeat(np.arange(len(count)), count)
    start = np.cumsum(count) - count
    local = np.arange(count.sum()) - np.repeat(start, count)
    w = np.maximum(width[tri], 1)
    return tri, i0[tri] + local // w, j0[tri] + local % w


def _barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(K, 3) barycentric coordinates of points p in triangles (a, b, c), all (K, 2) float64."""
    v0, v1, v2 = b - a, c - a, p - a
    d00 = (v0 * v0).sum(-1)
    d01 = (v0 * v1).sum(-1)
    d11 = (v1 * v1).sum(-1)
    d20 = (v2 * v0).sum(-1)
    d21 = (v2 * v1).sum(-1)
    denom = d00 * d11 - d01 * d01
    wb = (d11 * d20 - d01 * d21) / denom
    wc = (d00 * d21 - d01 * d20) / denom
    bary = np.stack([1.0 - wb - wc, wb, wc], axis=-1)
    bary = np.clip(bary, 0.0, None)
    return bary / bary.sum(-1, keepdims=True)


def _closest_on_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
    return a + t[:, None] * ab


def _closest_on_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(K, 2) closest points of (non-degenerate) triangles to points outside them."""
    candidates = np.stack([_closest_on_segment(p, a, b), _closest_on_segment(p, b, c), _closest_on_segment(p, c, a)])
    dist = ((candidates - p[None]) ** 2).sum(-1)
    return candidates[dist.argmin(0), np.arange(len(p))]


def rasterize_uv(uv_coords: np.ndarray, uv_faces: np.ndarray, resolution: int, dilate: bool = True) -> UVAtlas:
    """Rasterise UV triangles into an L x L atlas (rules in the module docstring).

    Args:
        uv_coords: (T, 2) texture coordinates, v up.
        uv_faces: (F, 3) indices into ``uv_coords``.
        resolution: L, a power of two from 32 to 1024.
        dilate: add boundary texels whose cell touches an island (rule 4).
    """
    resolution = check_resolution(resolution)
    uv_coords = np.asarray(uv_coords, dtype=np.float64)
    uv_faces = np.asarray(uv_faces, dtype=np.int64)
    # Texel-unit coordinates: x right (u), y down (1 - v).
    xy = np.stack([uv_coords[:, 0], 1.0 - uv_coords[:, 1]], axis=-1) * resolution
    fixed = np.round(xy * SUBTEXELS).astype(np.int64)
    # From here on the snapped corners are the triangles, for the candidate boxes and the
    # barycentrics as much as for the exact edge tests.
    xy = fixed / SUBTEXELS

    corners = fixed[uv_faces]  # (F, 3, 2)
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 2] - corners[:, 0]
    area2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    # Wind every triangle the same way so the top-left rule reads the same for all.
    flip = area2 < 0
    order = np.where(flip[:, None], [0, 2, 1], [0, 1, 2])
    corners = np.take_along_axis(corners, order[..., None], axis=1)
    nondegenerate = area2 != 0

    tri, row, col = _candidates(xy[uv_faces].min(1), xy[uv_faces].max(1), resolution)
    keep = nondegenerate[tri]
    tri, row, col = tri[keep], row[keep], col[keep]
    centre = np.stack([col * SUBTEXELS + SUBTEXELS // 2, row * SUBTEXELS + SUBTEXELS // 2], -1)
    inside = np.ones(len(tri), dtype=bool)
    for k in range(3):
        a = corners[tri, k]
        b = corners[tri, (k + 1) % 3]
        d = b - a
        edge = d[:, 0] * (centre[:, 1] - a[:, 1]) - d[:, 1] * (centre[:, 0] - a[:, 0])
        top_left = (d[:, 1] > 0) | ((d[:, 1] == 0) & (d[:, 0] < 0))
        inside &= (edge > 0) | ((edge == 0) & top_left)
    tri, row, col = tri[inside], row[inside], col[inside]

    flat = row * resolution + col
    by_texel = np.lexsort((tri, flat))
    flat, tri = flat[by_texel], tri[by_texel]
    first = np.ones(len(flat), dtype=bool)
    first[1:] = flat[1:] != flat[:-1]
    overlap_count = int(len(np.unique(flat[~first])))
    flat, tri = flat[first], tri[first]
    dilated = np.zeros(len(flat), dtype=bool)

    texel_xy = np.stack([flat % resolution + 0.5, flat // resolution + 0.5], -1).astype(np.float64)
    tri_xy = xy[uv_faces]
    bary = _barycentric(texel_xy, tri_xy[tri, 0], tri_xy[tri, 1], tri_xy[tri, 2])

    if dilate:
        d_flat, d_tri, d_bary = _dilate(xy, uv_faces, nondegenerate, flat, resolution)
        flat = np.concatenate([flat, d_flat])
        tri = np.concatenate([tri, d_tri])
        bary = np.concatenate([bary, d_bary])
        dilated = np.concatenate([dilated, np.ones(len(d_flat), dtype=bool)])
        order = np.argsort(flat, kind="stable")
        flat, tri, bary, dilated = flat[order], tri[order], bary[order], dilated[order]

    chart = uv_charts(uv_faces)[tri]
    return UVAtlas(
        resolution=resolution,
        texel_rc=torch.from_numpy(np.stack([flat // resolution, flat % resolution], -1)),
        face=torch.from_numpy(tri),
        barycentric=torch.from_numpy(bary.astype(np.float32)),
        chart=torch.from_numpy(chart.astype(np.int64)),
        dilated=torch.from_numpy(dilated),
        overlap_count=overlap_count,
    )


def _dilate(
    xy: np.ndarray,
    uv_faces: np.ndarray,
    nondegenerate: np.ndarray,
    covered_flat: np.ndarray,
    resolution: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uncovered texels within ``DILATION_RADIUS`` of a triangle: (flat, triangle, barycentric)."""
    tri_xy = xy[uv_faces]
    tri, row, col = _candidates(tri_xy.min(1) - DILATION_RADIUS, tri_xy.max(1) + DILATION_RADIUS, resolution)
    flat = row * resolution + col
    keep = nondegenerate[tri] & ~np.isin(flat, covered_flat)
    tri, flat = tri[keep], flat[keep]
    p = np.stack([flat % resolution + 0.5, flat // resolution + 0.5], -1).astype(np.float64)
    a, b, c = tri_xy[tri, 0], tri_xy[tri, 1], tri_xy[tri, 2]
    closest = _closest_on_triangle(p, a, b, c)
    dist = np.sqrt(((closest - p) ** 2).sum(-1))
    near = dist <= DILATION_RADIUS
    tri, flat, dist, closest = tri[near], flat[near], dist[near], closest[near]
    # Nearest triangle per texel, ties to the lowest triangle index.
    order = np.lexsort((tri, dist, flat))
    tri, flat, closest = tri[order], flat[order], closest[order]
    first = np.ones(len(flat), dtype=bool)
    first[1:] = flat[1:] != flat[:-1]
    tri, flat, closest = tri[first], flat[first], closest[first]
    bary = _barycentric(closest, tri_xy[tri, 0], tri_xy[tri, 1], tri_xy[tri, 2])
    return flat, tri, bary


def cache_dir() -> Path:
    """Where pghm caches derived data: ``$PGHM_CACHE_DIR`` or ``~/.cache/pghm``."""
    return Path(os.environ.get("PGHM_CACHE_DIR", Path.home() / ".cache" / "pghm"))


def _atlas_to_bytes(atlas: UVAtlas) -> bytes:
    buffer = io.BytesIO()
    np.savez(
        buffer,
        resolution=atlas.resolution,
        texel_rc=atlas.texel_rc.numpy().astype(np.int32),
        face=atlas.face.numpy().astype(np.int32),
        barycentric=atlas.barycentric.numpy(),
        chart=atlas.chart.numpy().astype(np.int32),
        dilated=atlas.dilated.numpy(),
        overlap_count=atlas.overlap_count,
    )
    return buffer.getvalue()


def _atlas_from_file(path: Path) -> UVAtlas:
    with np.load(path, allow_pickle=False) as data:
        return UVAtlas(
            resolution=int(data["resolution"]),
            texel_rc=torch.from_numpy(data["texel_rc"].astype(np.int64)),
            face=torch.from_numpy(data["face"].astype(np.int64)),
            barycentric=torch.from_numpy(data["barycentric"]),
            chart=torch.from_numpy(data["chart"].astype(np.int64)),
            dilated=torch.from_numpy(data["dilated"]),
            overlap_count=int(data["overlap_count"]),
        )


_MEMORY_CACHE: dict[tuple[str, int, bool], UVAtlas] = {}


def build_atlas(body, resolution: int = 128, dilate: bool = True, use_cache: bool = True) -> UVAtlas:
    """The atlas of ``body``'s UV layout at ``resolution``, cached in memory and on disk.

    Args:
        body: a :class:`~pghm.body.model.BodyModel`.
        resolution: L, a power of two from 32 to 1024.
        dilate: see rule 4 of the module docstring.
        use_cache: read and write the on-disk cache.
    """
    resolution = check_resolution(resolution)
    key = (body.identity_key(), resolution, dilate)
    if use_cache and key in _MEMORY_CACHE:
        return _MEMORY_CACHE[key]
    path = cache_dir() / "atlas" / f"{key[0]}-L{resolution}-d{int(dilate)}-v{ATLAS_FORMAT}.npz"
    atlas = None
    if use_cache and path.is_file():
        try:
            atlas = _atlas_from_file(path)
        except NPZ_READ_ERRORS:
            atlas = None  # a damaged cache entry is rebuilt below
    if atlas is None:
        atlas = rasterize_uv(body.uv_coords.numpy(), body.uv_faces.numpy(), resolution, dilate)
        if use_cache:
            atomic_write_bytes(path, _atlas_to_bytes(atlas))
    if use_cache:
        _MEMORY_CACHE[key] = atlas
    return atlas
