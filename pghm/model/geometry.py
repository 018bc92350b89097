"""The body-dependent constants of one subject: its canonical texel surface and skeleton.

A subject's body shape fixes the canonical texel positions V_bar, their normals and skinning
weights, the rest joints, and each texel's base Gaussian scale. They are buffers derived
from (body, atlas, shape), never trained and never saved: an avatar file stores the shape
and rebuilds them. An avatar with a detail layer (:mod:`pghm.model.detail`) also has the
same quantities at 2L.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from pghm.body.model import BodyModel, RestBody
from pghm.body.pose import BodyPose
from pghm.body.skinning import kinematic_levels, pose_transforms
from pghm.errors import PghmError
from pghm.model.config import ModelConfig
from pghm.model.detail import DETAIL_FACTOR, DetailGeometry, upsampling
from pghm.uv.atlas import UVAtlas, build_atlas
from pghm.uv.maps import TexelSurface, texel_surface


@dataclass(frozen=True)
class SubjectGeometry:
    """Canonical surface and skeleton of one body shape on one atlas.

    Attributes:
        atlas: the UV atlas (N valid texels).
        surface: canonical texel surface (positions, normals, weights, ...).
        joints: (J, 3) rest joints.
        parents: J parent indices.
        texel_length: (N,) surface length one texel spans at each texel, metres.
        shape: (S,) the body shape parameters.
        body_name: backend name.
        detail: the 2L texels of a detail layer, or None.
    """

    atlas: UVAtlas
    surface: TexelSurface
    joints: Tensor
    parents: list[int]
    texel_length: Tensor
    shape: Tensor
    body_name: str
    detail: DetailGeometry | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "_levels", kinematic_levels(self.parents, self.joints.device))

    @property
    def num_gaussians(self) -> int:
        return (self.atlas if self.detail is None else self.detail.atlas).num_texels

    def transforms(self, pose: BodyPose) -> Tensor:
        """(B, J, 4, 4) skinning transforms of ``pose``."""
        return pose_transforms(pose, self.joints.to(pose.rotations.dtype), self.parents, self._levels)


def texel_lengths(vertices: Tensor, faces: Tensor, uv_coords: Tensor, uv_faces: Tensor, atlas: UVAtlas) -> Tensor:
    """(N,) surface length spanned by one texel, from each texel's triangle.

    A triangle of 3D area A and UV area a (in texels^2, a = a_uv L^2) maps one texel onto
    A / a square metres, so one texel spans sqrt(A / a) metres there. Degenerate UV
    triangles (a = 0) get the median length.
    """
    corners = vertices[faces[atlas.face]]  # (N, 3, 3)
    area3d = 0.5 * torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]).norm(dim=-1)
    uv = uv_coords.to(vertices.dtype)[uv_faces[atlas.face]] * atlas.resolution  # (N, 3, 2)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area_uv = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).abs()
    valid = area_uv > 0
    length = torch.sqrt(area3d / area_uv.clamp_min(1e-12))
    return torch.where(valid, length, length[valid].median())


def subject_geometry(
    body: BodyModel, atlas: UVAtlas, shape: Tensor | None = None, detail_atlas: UVAtlas | None = None
) -> SubjectGeometry:
    """The geometry of ``body`` with ``shape`` (None: the default shape) on ``atlas``, and on the
    2L ``detail_atlas`` of a detail layer when given."""
    shape = body.check_shape(shape)
    rest = body.rest(shape)
    if not (bool(torch.isfinite(rest.vertices).all()) and bool(torch.isfinite(rest.joints).all())):
        values = [round(v, 4) for v in shape.tolist()]
        raise PghmError(f"the {body.name} body with shape {values} has non-finite vertices")
    texel_length = texel_lengths(rest.vertices, body.faces, body.uv_coords, body.uv_faces, atlas)
    return SubjectGeometry(
        atlas=atlas,
        surface=texel_surface(body, atlas, rest),
        joints=rest.joints,
        parents=list(body.parents),
        texel_length=texel_length,
        shape=shape.detach().clone(),
        body_name=body.name,
        detail=None if detail_atlas is None else _detail_geometry(body, atlas, detail_atlas, rest, texel_length),
    )


def detail_atlas(body: BodyModel, config: ModelConfig) -> UVAtlas | None:
    """The 2L atlas of a model ``config`` with a detail layer, None without one."""
    return build_atlas(body, DETAIL_FACTOR * config.uv_resolution) if config.detail else None


def _detail_geometry(
    body: BodyModel, atlas: UVAtlas, detail_atlas: UVAtlas, rest: RestBody, texel_length: Tensor
) -> DetailGeometry:
    source, weights = upsampling(atlas, detail_atlas)
    return DetailGeometry(
        atlas=detail_atlas,
        surface=texel_surface(body, detail_atlas, rest),
        texel_length=(texel_length[source] * weights.to(texel_length.dtype)).sum(-1),
        source=source,
        weights=weights,
    )
