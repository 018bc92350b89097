"""The UV atlas: rasterisation rules, coverage of the body's charts, the on-disk cache."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from geometry import distance_to_mesh

from pghm.errors import PghmError
from pghm.uv import atlas as atlas_module
from pghm.uv.atlas import DILATION_RADIUS, build_atlas, rasterize_uv, uv_charts
from pghm.uv.maps import texel_surface


def test_square_of_two_triangles_is_covered_exactly_once():
    """The shared diagonal passes through texel centres: the top-left rule gives each to one triangle."""
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    atlas = rasterize_uv(uv, faces, 32)
    assert atlas.num_texels == 32 * 32
    assert atlas.overlap_count == 0 and not atlas.dilated.any()
    assert len(torch.unique(atlas.flat_index)) == atlas.num_texels
    # The diagonal texels (row i, column 31 - i) sit exactly on the shared edge.
    diagonal = atlas.texel_rc[:, 0] + atlas.texel_rc[:, 1] == 31
    assert diagonal.sum() == 32 and len(torch.unique(atlas.face[diagonal])) == 1


def test_barycentrics_reproduce_texel_centres(body, atlas128):
    uv = body.uv_coords.double()[body.uv_faces[atlas128.face]]  # (N, 3, 2)
    recon = (uv * atlas128.barycentric.double()[:, :, None]).sum(1)
    inside = ~atlas128.dilated
    # Corners are snapped to 1/256 texel before rasterising.
    err = (recon[inside] - atlas128.texel_uv()[inside]).abs().max() * atlas128.resolution
    assert err < 2.0 / atlas_module.SUBTEXELS
    bary = atlas128.barycentric
    assert (bary >= 0).all() and torch.allclose(bary.sum(-1), torch.ones(len(bary)))


def test_mirrored_overlap_keeps_lowest_face():
    uv = np.array([[0.1, 0.1], [0.9, 0.1], [0.5, 0.9]])
    faces = np.array([[0, 1, 2], [0, 2, 1]])  # the same triangle, wound the other way
    atlas = rasterize_uv(uv, faces, 32, dilate=False)
    assert atlas.overlap_count == atlas.num_texels > 0
    assert (atlas.face == 0).all()


def test_thin_island_survives_by_dilation():
    """A sliver a fifth of a texel wide, between texel centres, still gets texels."""
    uv = np.array([[0.1, 0.5 + 0.05 / 32], [0.9, 0.5 + 0.05 / 32], [0.9, 0.5 + 0.25 / 32]])
    faces = np.array([[0, 1, 2]])
    assert rasterize_uv(uv, faces, 32, dilate=False).num_texels == 0
    atlas = rasterize_uv(uv, faces, 32)
    assert atlas.num_texels > 0 and atlas.dilated.all()


@pytest.mark.parametrize("resolution", [64, 128])
def test_every_texel_lies_on_the_canonical_surface(body, rest, resolution):
    atlas = build_atlas(body, resolution)
    surface = texel_surface(body, atlas, body.rest(dtype=torch.float64))
    dist = distance_to_mesh(surface.positions, rest.vertices.double(), body.faces)
    assert dist.max() < 1e-5


def test_texels_cover_every_chart(body, atlas128):
    charts = uv_charts(body.uv_faces.numpy())
    assert set(torch.unique(atlas128.chart).tolist()) == set(range(charts.max() + 1))

    # No valid texel is isolated: each has an 8-neighbour in its own chart.
    size = atlas128.resolution
    chart_map = torch.full((size + 2, size + 2), -1, dtype=torch.long)
    rc = atlas128.texel_rc + 1
    chart_map[rc[:, 0], rc[:, 1]] = atlas128.chart
    has_neighbour = torch.zeros(atlas128.num_texels, dtype=torch.bool)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di or dj:
                has_neighbour |= chart_map[rc[:, 0] + di, rc[:, 1] + dj] == atlas128.chart
    assert has_neighbour.all()

    # Every point of every chart lies within half a texel diagonal of a valid texel centre.
    gen = np.random.default_rng(0)
    uv = body.uv_coords.numpy().astype(np.float64)[body.uv_faces.numpy()]  # (F, 3, 2)
    weights = gen.dirichlet(np.ones(3), size=(len(uv), 4))  # 4 random points per triangle
    points = np.einsum("fkc,fsk->fsc", uv, weights).reshape(-1, 2)
    # Nearest valid texel centre among the 3 x 3 texels around each point (enough to find
    # any centre within one texel).
    valid = atlas128.mask.numpy()
    x, y = points[:, 0] * size, (1.0 - points[:, 1]) * size
    col0, row0 = np.floor(x).astype(int), np.floor(y).astype(int)
    nearest = np.full(len(points), np.inf)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            row, col = np.clip(row0 + di, 0, size - 1), np.clip(col0 + dj, 0, size - 1)
            dist = np.hypot(x - (col + 0.5), y - (row + 0.5))
            nearest = np.where(valid[row, col], np.minimum(nearest, dist), nearest)
    assert nearest.max() <= DILATION_RADIUS + 1e-6


def test_texel_counts_and_uniqueness(body):
    for resolution in (64, 128, 256):
        atlas = build_atlas(body, resolution)
        assert len(torch.unique(atlas.flat_index)) == atlas.num_texels
        assert atlas.overlap_count == 0
        assert (atlas.flat_index.diff() > 0).all()  # row-major order
    # Roughly 68% of the square is inside the MakeHuman charts.
    assert 0.6 < build_atlas(body, 128).num_texels / 128**2 < 0.75


def test_rasterisation_is_deterministic(body):
    a = rasterize_uv(body.uv_coords.numpy(), body.uv_faces.numpy(), 64)
    b = rasterize_uv(body.uv_coords.numpy(), body.uv_faces.numpy(), 64)
    for field in ("texel_rc", "face", "barycentric", "chart", "dilated"):
        assert torch.equal(getattr(a, field), getattr(b, field))


def test_disk_cache_round_trip(body, tmp_path, monkeypatch):
    monkeypatch.setenv("PGHM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(atlas_module, "_MEMORY_CACHE", {})
    built = build_atlas(body, 64)
    assert list((tmp_path / "atlas").glob("*.npz"))
    monkeypatch.setattr(atlas_module, "_MEMORY_CACHE", {})
    monkeypatch.setattr(atlas_module, "rasterize_uv", None)  # must not be called
    loaded = build_atlas(body, 64)
    for field in ("texel_rc", "face", "barycentric", "chart", "dilated"):
        assert torch.equal(getattr(built, field), getattr(loaded, field))


def test_damaged_cache_is_rebuilt(body, tmp_path, monkeypatch):
    monkeypatch.setenv("PGHM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(atlas_module, "_MEMORY_CACHE", {})
    build_atlas(body, 32)
    (cached,) = (tmp_path / "atlas").glob("*.npz")
    cached.write_bytes(b"not an npz")
    monkeypatch.setattr(atlas_module, "_MEMORY_CACHE", {})
    assert build_atlas(body, 32).num_texels > 0


@pytest.mark.parametrize("resolution", [16, 48, 2048, 128.0])
def test_bad_resolution(body, resolution):
    with pytest.raises(PghmError, match="power of two"):
        build_atlas(body, resolution)
