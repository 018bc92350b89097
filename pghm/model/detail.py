"""The detail layer: Gaussians at twice the UV resolution, with residuals trained texel by texel.

The network's maps are L x L; one Gaussian per valid texel bounds the avatar's detail to the
texel spacing, and the U-Net's smooth output to less. The detail layer places the Gaussians on
the texels of a 2L atlas instead (four times as many) and gives each its own trainable colour,
scale and small lift along the surface normal, optimised directly (no network):

    X_2L     = upsample(X_L)                       every gathered network output (pre-activation)
    c        = sigmoid(U_c(2L) + D_c)                  D_c: colour-logit residual (3 per 2L texel)
    s        = base(L) exp(ln r tanh(U_s(2L) + D_s))   D_s: log-scale residual (1)
    x        = x_surface(2L) + offsets(2L) + a_d tanh(D_h) n_theta        D_h: lift (1), a_d: max_detail_offset

``base(L)`` is the L texel's base scale, upsampled like the rest: a zero layer draws Gaussians as
large as the L model's, four times as densely, so its outline is the L model's (Gaussians of the 2L
texel's own size, half as large, thin the outline by half an L Gaussian, which costs the held-out
frames of a real video before any training: docs/lab/detail-layer.md). Where detail pays, the
trained D_s shrinks them (down to 1/r, the same bound as ever).

``upsample`` is bilinear in UV, as ``F.interpolate(scale_factor=2, align_corners=False)`` would
be inside a chart: a 2L texel centre lies a quarter of an L texel from its four nearest L texel
centres, weighted 9/16, 3/16, 3/16, 1/16 (exact in binary floating point). Unlike the image
operation it takes only L texels of the 2L texel's own UV chart (an invalid texel's network
output is never trained, and across a seam lies another part of the body) and renormalises
their weights; a 2L texel with none of its four neighbours in its chart takes its chart's
nearest L texel. On a field linear in UV the interior texels are therefore exact.

The residuals live in one dense map (1, 5, 2L, 2L) (zero at invalid texels), so their shape
follows from the model config alone and the avatar file validates them like every weight.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from pghm.body.skinning import blend_transform_deltas, rotate_directions
from pghm.uv.atlas import UVAtlas
from pghm.uv.maps import TexelSurface, barycentric_blend, posed_points

DETAIL_FACTOR = 2
"""The detail atlas's resolution over the network's L."""
DETAIL_CHANNELS = 5
"""Detail map channels: log-scale residual (1), colour-logit residual (3) (D_static's channels 3..6),
lift along the normal before tanh (1)."""
LIFT_CHANNEL = 4
"""The detail map channel of the lift."""
NEIGHBOURS = 4
"""L texels each 2L texel blends (bilinear)."""


@dataclass(frozen=True)
class DetailGeometry:
    """The 2L texels of one subject and how they sample the L maps.

    Attributes:
        atlas: the 2L atlas (N2 valid texels).
        surface: its canonical texel surface.
        texel_length: (N2,) the L texel's surface length, upsampled: the base scale's (module docstring).
        source: (N2, 4) long L texel indices each 2L texel blends.
        weights: (N2, 4) their weights (sum 1; 0 for a neighbour left out).
    """

    atlas: UVAtlas
    surface: TexelSurface
    texel_length: Tensor
    source: Tensor
    weights: Tensor


@dataclass
class DetailSkinned:
    """The posed 2L texels (what :class:`~pghm.model.pghm.Skinned` holds for the L texels).

    Attributes:
        surface_points: (B, N2, 3) posed texel points on the skinned mesh.
        rotation_delta: (B, N2, 3, 3) blended rotation minus identity.
        normals: (B, N2, 3) posed unit normals.
    """

    surface_points: Tensor
    rotation_delta: Tensor
    normals: Tensor

    def select(self, index: Tensor) -> DetailSkinned:
        """The poses ``index`` (B,) of this batch."""
        return DetailSkinned(self.surface_points[index], self.rotation_delta[index], self.normals[index])


def pose_detail(surface: TexelSurface, transforms: Tensor) -> DetailSkinned:
    """The 2L texels of ``surface`` posed by (B, J, 4, 4) ``transforms``, as the model's ``skin`` poses
    the L texels. Each texel's blended transform is the barycentric blend of its corners' ones,

        sum_j W[n, j] A_j = sum_k b_n[k] (sum_j W[v_k, j] A_j)       (W[n] = sum_k b_n[k] W[v_k]),

    so the J-term blend runs per vertex (V rows) rather than per 2L texel (N2 = 3 V rows at L = 128).
    """
    vertex_deltas = blend_transform_deltas(surface.vertex_weights, transforms)[..., :3]  # (B, V, 3, 3)
    deltas = barycentric_blend(vertex_deltas.flatten(-2), surface.corners, surface.barycentric).unflatten(-1, (3, 3))
    return DetailSkinned(
        surface_points=posed_points(surface, transforms),
        rotation_delta=deltas,
        normals=rotate_directions(surface.normals, deltas),
    )


class DetailLayer(nn.Module):
    """The trainable residual map ``maps`` (1, 5, 2L, 2L), zero at creation (a zero layer adds nothing
    but the finer sampling)."""

    def __init__(self, uv_resolution: int) -> None:
        super().__init__()
        size = DETAIL_FACTOR * uv_resolution
        self.maps = nn.Parameter(torch.zeros(1, DETAIL_CHANNELS, size, size))


def _texel_lookup(atlas: UVAtlas) -> Tensor:
    """(L * L,) long: the texel number of each map cell, -1 where invalid."""
    lookup = torch.full((atlas.resolution**2,), -1, dtype=torch.long)
    lookup[atlas.flat_index] = torch.arange(atlas.num_texels)
    return lookup


def _nearest_in_chart(coarse: UVAtlas, fine: UVAtlas, orphans: Tensor) -> Tensor:
    """(M,) the L texel nearest (in UV) to each 2L texel ``orphans`` (M,), within its chart when the
    chart has L texels, else anywhere."""
    distance = torch.cdist(fine.texel_uv()[orphans], coarse.texel_uv())  # (M, N)
    other_chart = fine.chart[orphans, None] != coarse.chart[None, :]
    has_chart = ~other_chart.all(1, keepdim=True)
    return distance.masked_fill(other_chart & has_chart, torch.inf).argmin(1)


def upsampling(coarse: UVAtlas, fine: UVAtlas) -> tuple[Tensor, Tensor]:
    """The bilinear blend (module docstring) of L atlas ``coarse`` onto 2L atlas ``fine``.

    Returns:
        source: (N2, 4) long L texel indices.
        weights: (N2, 4) float32 weights, summing to 1 per 2L texel.
    """
    size = coarse.resolution
    lookup = _texel_lookup(coarse)
    # A 2L texel centre in L texel coordinates: (k + 1/2) / 2 - 1/2.
    centre = (fine.texel_rc.double() + 0.5) / DETAIL_FACTOR - 0.5  # (N2, 2) row, column
    low = centre.floor().long()
    frac = centre - low
    sources, weights = [], []
    for dr in (0, 1):
        for dc in (0, 1):
            row, column = low[:, 0] + dr, low[:, 1] + dc
            inside = (row >= 0) & (row < size) & (column >= 0) & (column < size)
            texel = torch.where(inside, lookup[row.clamp(0, size - 1) * size + column.clamp(0, size - 1)], -1)
            weight = (frac[:, 0] if dr else 1 - frac[:, 0]) * (frac[:, 1] if dc else 1 - frac[:, 1])
            usable = (texel >= 0) & (coarse.chart[texel.clamp_min(0)] == fine.chart)
            sources.append(texel.clamp_min(0))
            weights.append(torch.where(usable, weight, 0.0))
    source, weight = torch.stack(sources, -1), torch.stack(weights, -1)
    total = weight.sum(-1, keepdim=True)
    orphans = torch.nonzero(total[:, 0] == 0)[:, 0]
    if len(orphans):
        source[orphans, 0] = _nearest_in_chart(coarse, fine, orphans)
        weight[orphans, 0], total[orphans] = 1.0, 1.0
    return source, (weight / total).float()


def upsample(values: Tensor, detail: DetailGeometry) -> Tensor:
    """(B, N2, C) per-2L-texel values blended from per-L-texel ``values`` (B, N, C)."""
    blended = values[:, detail.source]  # (B, N2, 4, C)
    return (blended * detail.weights.to(values.dtype)[None, :, :, None]).sum(2)
