"""An identity made concrete on the body model: clothed canonical mesh and its textures.

:func:`build_clothed_body` runs once per identity (painting dominates: ~0.7 s at L = 512,
~2.5 s at L = 1024); :func:`pose_clothed_body` runs per batch of poses:

    x_rest'  = x_rest + o + FOLD_GEOMETRY_DEPTH sum_k a_k G_k(x_rest) n_rest   (cloth, folds)
    x        = LBS(x_rest', W', A(theta))                                         (posing)

with o the static cloth displacement, n_rest the rest vertex normal, G_k the fold patterns at
the vertices, a_k the pose's fold amplitudes and W' the body's skinning weights with a
skirt's partly moved to the root (:mod:`.cloth`). Normals are recomputed
from the posed mesh, so loose cloth and folds shade correctly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from pghm.body import BodyModel, RestBody, lbs
from pghm.synth import cloth
from pghm.synth.identity import Identity
from pghm.synth.paint import paint_albedo, texels_to_map
from pghm.synth.regions import (
    PART_NAMES,
    Landmarks,
    SurfacePoints,
    bone_parts,
    describe_points,
    landmarks,
)
from pghm.uv.atlas import build_atlas
from pghm.uv.maps import barycentric_blend, vertex_normals


@dataclass(frozen=True)
class ClothedBody:
    """One identity on one body: canonical geometry and UV maps.

    Attributes:
        joints: (J, 3) rest joints of the identity's shape.
        weights: (V, J) float64 skinning weights (the body's, a skirt's blended to the root).
        vertices: (V, 3) float64 clothed rest vertices (cloth offsets applied, no folds).
        normals: (V, 3) float64 unit rest normals of the unclothed body (offset directions).
        vertex_folds: (V, 8) fold patterns G_k at the vertices.
        albedo: (L, L, 4) uint8 sRGB albedo and specular strength, row 0 = top (v = 1).
        wrinkles: (L, L, 8) float32 fold patterns G_k, same layout.
        marks: the shaped body's landmarks.
    """

    joints: torch.Tensor
    weights: torch.Tensor
    vertices: np.ndarray
    normals: np.ndarray
    vertex_folds: np.ndarray
    albedo: np.ndarray
    wrinkles: np.ndarray
    marks: Landmarks


def part_weights(body: BodyModel) -> np.ndarray:
    """(V, P) skinning weight of every vertex summed per body part."""
    parts = bone_parts(body.bone_names, body.parents, body.joint_map)
    weights = body.skin_weights.numpy().astype(np.float64)
    summed = np.zeros((weights.shape[0], len(PART_NAMES)))
    for part in range(len(PART_NAMES)):
        summed[:, part] = weights[:, parts == part].sum(1)
    return summed


def shaped_body(body: BodyModel, identity: Identity) -> tuple[RestBody, Landmarks]:
    """The identity's rest body (float64) and its landmarks."""
    rest = body.rest(torch.tensor(identity.shape, dtype=torch.float32), dtype=torch.float64)
    vertex_parts = part_weights(body).argmax(1)
    marks = landmarks(rest.vertices.numpy(), rest.joints.numpy(), vertex_parts, body.joint_map, body.bone_names)
    return rest, marks


def build_clothed_body(
    body: BodyModel,
    identity: Identity,
    texture_size: int,
    cloth_geometry: bool = True,
    wrinkles: bool = True,
) -> ClothedBody:
    """Paint and dress ``identity`` on ``body``.

    Args:
        body: the body model (its part structure must follow the canonical joints).
        identity: the person.
        texture_size: L, the UV map resolution (a power of two).
        cloth_geometry: displace the mesh by the cloth offsets (False: skin-tight paint).
        wrinkles: give the joints fold patterns (False: all G_k = 0).
    """
    rest, marks = shaped_body(body, identity)
    vertices = rest.vertices.numpy()
    normals = vertex_normals(rest.vertices, body.faces).numpy()
    weights_per_part = part_weights(body)
    phases = np.random.default_rng(identity.texture_seed).uniform(0, 2 * np.pi, (len(cloth.WRINKLE_JOINTS), 2))

    def dress(points: SurfacePoints) -> tuple[np.ndarray, np.ndarray]:
        labels = cloth.material_labels(points, marks, identity)
        folds = cloth.fold_patterns(points, labels, marks, identity, phases)
        return labels, folds if wrinkles else np.zeros_like(folds)

    at_vertices = describe_points(vertices, normals, weights_per_part, marks)
    vertex_labels, vertex_folds = dress(at_vertices)
    shift = cloth.cloth_displacements(at_vertices, vertex_labels, marks, identity) if cloth_geometry else 0.0
    weights = body.skin_weights.double()
    if cloth_geometry:
        beta = torch.from_numpy(cloth.skirt_pelvis_weight(at_vertices, vertex_labels, marks, identity))[:, None]
        weights = (1 - beta) * weights + beta * torch.nn.functional.one_hot(torch.tensor(0), weights.shape[1])

    atlas = build_atlas(body, texture_size)
    corners = body.faces[atlas.face]
    bary = atlas.barycentric.to(torch.float64)
    texel_normals = barycentric_blend(torch.from_numpy(normals), corners, bary).numpy()
    texel_normals /= np.maximum(np.linalg.norm(texel_normals, axis=1, keepdims=True), 1e-12)
    at_texels = describe_points(
        barycentric_blend(rest.vertices, corners, bary).numpy(),
        texel_normals,
        barycentric_blend(torch.from_numpy(weights_per_part), corners, bary).numpy(),
        marks,
    )
    texel_labels, texel_folds = dress(at_texels)
    albedo = paint_albedo(at_texels, texel_labels, marks, identity)
    return ClothedBody(
        joints=rest.joints,
        weights=weights,
        vertices=vertices + shift,
        normals=normals,
        vertex_folds=vertex_folds,
        albedo=np.round(texels_to_map(albedo, atlas) * 255).astype(np.uint8),
        wrinkles=texels_to_map(texel_folds, atlas).astype(np.float32),
        marks=marks,
    )


def pose_clothed_body(
    body: BodyModel,
    clothed: ClothedBody,
    rotations: np.ndarray,
    translation: np.ndarray,
    fold_amplitudes: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Posed clothed meshes (module docstring).

    Args:
        body: the body model.
        clothed: the identity on it.
        rotations: (B, J, 3) axis-angle poses.
        translation: (B, 3) root translations.
        fold_amplitudes: (B, 8) a_k per pose.

    Returns:
        positions: (B, V, 3) float32 posed vertices.
        normals: (B, V, 3) float32 posed unit vertex normals.
    """
    pose = body.pose_from_arrays(torch.from_numpy(rotations).double(), torch.from_numpy(translation).double())
    transforms = body.bone_transforms(pose, clothed.joints)
    fold_height = cloth.FOLD_GEOMETRY_DEPTH * (fold_amplitudes @ clothed.vertex_folds.T)  # (B, V)
    canonical = clothed.vertices[None] + fold_height[..., None] * clothed.normals[None]
    posed = lbs(torch.from_numpy(canonical), clothed.weights, transforms)
    normals = torch.stack([vertex_normals(frame, body.faces) for frame in posed])
    return posed.float().numpy(), normals.float().numpy()
