"""UV maps of the paper, built on an atlas: canonical texel points, U_theta and V.

Each valid texel n of the atlas carries the surface point with barycentric coordinates
b_n in triangle f_n = (v0, v1, v2):

    canonical position  V_bar[n] = sum_k b_n[k] rest_vertices[v_k]
    skinning weights    W[n, j]  = sum_k b_n[k] skin_weights[v_k, j]
    canonical normal    N_bar[n] = normalize(sum_k b_n[k] vertex_normals[v_k])

Texel points ride on the posed mesh. A texel point with an offset d from its surface
point (the model's position offsets) is posed as

    x_n = sum_k b_n[k] LBS(v_k) + (I + sum_j W[n, j] (R_j - I)) d

the barycentric blend of the skinned triangle corners (so with d = 0 it is exactly the
point of the posed mesh surface its UV addresses, the surface the synthetic data is drawn
from) plus the offset rotated by the texel's blended transform. Plain LBS of the texel
point with the blended weights would differ from the posed surface by the cross terms
sum_k b_k (M_k - M_n)(v_k - V_bar[n]), millimetres near bent joints. From a posed body:

    U_theta (uv_position_map)   the posed positions scattered into an L x L x 3 map,
    V (view_direction_map)      per texel, the unit vector from the posed point to the
                                camera centre, with the posed normals beside it.

Maps are channels-first, (B, C, L, L), the layout the network convolves; invalid texels
hold zeros.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from pghm.body.model import BodyModel, RestBody
from pghm.body.skinning import blend_transform_deltas, lbs, safe_normalize, skin_directions
from pghm.uv.atlas import UVAtlas


@dataclass(frozen=True)
class TexelSurface:
    """The canonical surface points one atlas carries for one body shape.

    Attributes:
        vertices: (V, 3) rest vertices of the shaped body.
        vertex_weights: (V, J) skinning weights of the vertices.
        corners: (N, 3) long vertex indices of each texel's triangle.
        barycentric: (N, 3) barycentric coordinates of each texel in it.
        positions: (N, 3) canonical texel positions V_bar.
        normals: (N, 3) canonical unit normals.
        weights: (N, J) skinning weights of the texels.
    """

    vertices: Tensor
    vertex_weights: Tensor
    corners: Tensor
    barycentric: Tensor
    positions: Tensor
    normals: Tensor
    weights: Tensor


def vertex_normals(vertices: Tensor, faces: Tensor) -> Tensor:
    """(V, 3) area-weighted unit vertex normals of a triangle mesh (V, 3), (F, 3)."""
    corners = vertices[faces]  # (F, 3, 3)
    face_normals = torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = torch.zeros_like(vertices).index_add_(0, faces.reshape(-1), face_normals.repeat_interleave(3, dim=0))
    return safe_normalize(normals)


def barycentric_blend(values: Tensor, corners: Tensor, barycentric: Tensor) -> Tensor:
    """(..., N, C) texel values blended from per-vertex values (..., V, C).

    Args:
        values: (..., V, C) per-vertex values.
        corners: (N, 3) vertex indices of each texel's triangle.
        barycentric: (N, 3) the texels' barycentric coordinates.
    """
    at_corners = values[..., corners, :]  # (..., N, 3, C)
    return (at_corners * barycentric.to(values.dtype)[:, :, None]).sum(-2)


def texel_surface(body: BodyModel, atlas: UVAtlas, rest: RestBody) -> TexelSurface:
    """Canonical texel positions, normals and skinning weights for a shaped rest body."""
    dtype = rest.vertices.dtype
    corners = body.faces[atlas.face]
    bary = atlas.barycentric.to(dtype)
    vertex_weights = body.skin_weights.to(dtype)
    normals = vertex_normals(rest.vertices, body.faces)
    return TexelSurface(
        vertices=rest.vertices,
        vertex_weights=vertex_weights,
        corners=corners,
        barycentric=bary,
        positions=barycentric_blend(rest.vertices, corners, bary),
        normals=safe_normalize(barycentric_blend(normals, corners, bary)),
        weights=barycentric_blend(vertex_weights, corners, bary),
    )


def scatter_to_map(values: Tensor, atlas: UVAtlas) -> Tensor:
    """(B, C, L, L) map holding per-texel ``values`` (B, N, C) at the valid texels, 0 elsewhere."""
    batch, _, channels = values.shape
    size = atlas.resolution
    flat = values.new_zeros(batch, channels, size * size)
    flat = flat.index_copy(2, atlas.flat_index, values.transpose(1, 2))
    return flat.view(batch, channels, size, size)


def gather_from_map(maps: Tensor, atlas: UVAtlas) -> Tensor:
    """(B, N, C) values of the valid texels of maps (B, C, L, L)."""
    return maps.flatten(2).index_select(2, atlas.flat_index).transpose(1, 2)


def posed_points(surface: TexelSurface, transforms: Tensor, offsets: Tensor | None = None) -> Tensor:
    """Texel points, optionally offset, posed on the skinned mesh (module docstring).

    Args:
        surface: the canonical texel surface.
        transforms: (B, J, 4, 4) skinning transforms.
        offsets: (N, 3) or (B, N, 3) canonical offsets from the surface points, or None.

    Returns:
        points: (B, N, 3).
    """
    skinned_vertices = lbs(surface.vertices, surface.vertex_weights, transforms)  # (B, V, 3)
    points = barycentric_blend(skinned_vertices, surface.corners, surface.barycentric)
    if offsets is None:
        return points
    rotation_delta = blend_transform_deltas(surface.weights, transforms)[..., :3]  # (B, N, 3, 3)
    offsets = offsets.to(points.dtype)
    return points + offsets + (rotation_delta @ offsets[..., None])[..., 0]


def uv_position_map(surface: TexelSurface, atlas: UVAtlas, transforms: Tensor) -> Tensor:
    """U_theta: (B, 3, L, L) posed texel positions for (B, J, 4, 4) skinning transforms."""
    return scatter_to_map(posed_points(surface, transforms), atlas)


def view_directions(points: Tensor, camera_centres: Tensor) -> Tensor:
    """(B, N, 3) unit vectors from posed points (B, N, 3) to camera centres (B, 3).

    A point exactly at the camera centre gets a zero vector, not NaN.
    """
    return safe_normalize(camera_centres[:, None, :] - points)


def view_direction_map(
    surface: TexelSurface, atlas: UVAtlas, transforms: Tensor, camera_centres: Tensor
) -> tuple[Tensor, Tensor]:
    """V and the posed normals, both (B, 3, L, L), for cameras centred at (B, 3)."""
    points = posed_points(surface, transforms)
    directions = view_directions(points, camera_centres)
    normals = skin_directions(surface.normals, surface.weights, transforms)
    return scatter_to_map(directions, atlas), scatter_to_map(normals, atlas)
