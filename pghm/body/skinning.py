"""Forward kinematics and linear blend skinning (one idea per function, as smplx's ``lbs.py``).

Notation: J bones with rest joint positions ``joints`` (the heads the bones rotate about),
``parents[j]`` the parent of bone j (-1 for the root, bone 0), pose rotations R_j in
rest-aligned axes (see :mod:`pghm.body.pose`). Each bone's local motion is a rotation about
its own rest joint, the root's also a translation:

    L_j    = [R_j | joints_j - R_j joints_j]            (+ translation for the root)
    A_root = L_root,    A_j = A_parent(j) L_j            (the skinning transform of bone j)

which equals SMPL's A_j = G_j [I | -joints_j] with G_j the global joint frames. A point x
carried with weights w (sum_j w_j = 1) is skinned as

    x' = x + sum_j w_j (A_j - I) [x; 1]                  (linear blend skinning)

the same as sum_j w_j A_j [x; 1] when the weights sum to one, but written so that the
rest pose (every R_j = I, so every L_j and A_j is exactly the identity) returns x
bit-exactly, whatever the rounding of the weights.
"""

from __future__ import annotations

import roma
import torch
from torch import Tensor

from pghm.body.pose import BodyPose
from pghm.device import constant


def kinematic_levels(parents: list[int], device: torch.device | None = None) -> list[Tensor]:
    """Bones grouped by depth in the tree, root level first.

    Every bone's parent lies in an earlier level, so each level's global transforms are
    one batched product with the previous levels' results.

    Returns:
        levels: list of (J_level,) long tensors of bone indices, on ``device`` (None: the CPU).
    """
    depth = [0] * len(parents)
    for bone, parent in enumerate(parents):
        if parent >= bone and parent >= 0:
            raise ValueError(f"bone {bone} has parent {parent}: parents must precede children")
        depth[bone] = 0 if parent < 0 else depth[parent] + 1
    levels: list[list[int]] = [[] for _ in range(max(depth) + 1)]
    for bone, d in enumerate(depth):
        levels[d].append(bone)
    return [torch.tensor(level, dtype=torch.long, device=device) for level in levels]


def forward_kinematics(
    rotmats: Tensor,
    joints: Tensor,
    translation: Tensor,
    parents: list[int],
    levels: list[Tensor] | None = None,
) -> Tensor:
    """Skinning transforms A_j of every bone.

    Args:
        rotmats: (B, J, 3, 3) per-bone rotations in rest-aligned axes.
        joints: (J, 3) or (B, J, 3) rest joint positions.
        translation: (B, 3) root translation.
        parents: J parent indices, -1 for the root (which must be bone 0).
        levels: output of :func:`kinematic_levels`, recomputed when None.

    Returns:
        transforms: (B, J, 4, 4), A_j = A_parent(j) L_j.
    """
    levels = kinematic_levels(parents, rotmats.device) if levels is None else levels
    batch, num_bones = rotmats.shape[:2]
    joints = joints.expand(batch, num_bones, 3)
    # l[b, j] = joints[b, j] - R[b, j] joints[b, j], the translation of L_j.
    local_trans = joints - (rotmats @ joints[..., None])[..., 0]
    local_trans = local_trans + torch.nn.functional.pad(translation[:, None], (0, 0, 0, num_bones - 1))

    # Rotation Q and translation a of every A_j, filled one depth level at a time.
    parent_index = constant(tuple(max(p, 0) for p in parents), torch.long, rotmats.device)
    root = levels[0]
    rot = torch.zeros_like(rotmats).index_copy(1, root, rotmats[:, root])
    trans = torch.zeros_like(joints).index_copy(1, root, local_trans[:, root])
    for level in levels[1:]:
        parent = parent_index[level]
        parent_rot = rot[:, parent]
        # A_j = A_p L_j: rotation Q_p R_j, translation Q_p l_j + a_p.
        rot = rot.index_copy(1, level, parent_rot @ rotmats[:, level])
        trans = trans.index_copy(1, level, (parent_rot @ local_trans[:, level, :, None])[..., 0] + trans[:, parent])
    top = torch.cat([rot, trans[..., None]], dim=-1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


def pose_transforms(pose: BodyPose, joints: Tensor, parents: list[int], levels: list[Tensor] | None = None) -> Tensor:
    """Skinning transforms for a :class:`BodyPose`: (B, J, 4, 4)."""
    rotmats = roma.rotvec_to_rotmat(pose.rotations)
    return forward_kinematics(rotmats, joints.to(rotmats.dtype), pose.translation, parents, levels)


def blend_transform_deltas(weights: Tensor, transforms: Tensor) -> Tensor:
    """Per-point blended transforms, minus the identity.

    Args:
        weights: (N, J) skinning weights, rows summing to one.
        transforms: (B, J, 4, 4) skinning transforms.

    Returns:
        deltas: (B, N, 3, 4) with deltas[b, n] = sum_j weights[n, j] (A[b, j] - I)[:3].
    """
    batch, bones = transforms.shape[:2]
    identity = torch.eye(3, 4, dtype=transforms.dtype, device=transforms.device)
    # M[b, n, k] = sum_j W[n, j] (A - I)[b, j, k] over the 12 entries k of the top 3x4 block, as one
    # (N, J) x (J, 12 B) product: the weights are shared by the batch, and one product 12 B columns
    # wide runs faster than B products 12 wide, forward and backward (docs/lab/fit-speed.md).
    columns = (transforms[..., :3, :] - identity).reshape(batch, bones, 12).transpose(0, 1).reshape(bones, batch * 12)
    return (weights.to(columns.dtype) @ columns).view(-1, batch, 3, 4).transpose(0, 1)


def lbs(points_canonical: Tensor, weights: Tensor, transforms: Tensor) -> Tensor:
    """Linear blend skinning of arbitrary canonical points.

    Args:
        points_canonical: (N, 3) or (B, N, 3) canonical positions.
        weights: (N, J) skinning weights of the points (for texels: the barycentric blend
            of their triangle's vertex weights).
        transforms: (B, J, 4, 4) skinning transforms from :func:`forward_kinematics`.

    Returns:
        points: (B, N, 3) posed positions.
    """
    deltas = blend_transform_deltas(weights, transforms)
    points = points_canonical.to(deltas.dtype)
    return points + (deltas[..., :3] @ points[..., None])[..., 0] + deltas[..., 3]


def skin_directions(directions: Tensor, weights: Tensor, transforms: Tensor) -> Tensor:
    """Rotate canonical directions (normals) with the blended linear part, then normalise.

    Args:
        directions: (N, 3) or (B, N, 3) canonical unit vectors.
        weights: (N, J) skinning weights.
        transforms: (B, J, 4, 4).

    Returns:
        directions: (B, N, 3) unit vectors; a direction blended to zero length stays zero
        instead of becoming NaN.
    """
    return rotate_directions(directions, blend_transform_deltas(weights, transforms)[..., :3])


def rotate_directions(directions: Tensor, rotation_delta: Tensor) -> Tensor:
    """Directions (N, 3) or (B, N, 3) rotated by the blended linear parts I + D, ``rotation_delta``
    D (B, N, 3, 3) (:func:`blend_transform_deltas`), then normalised as :func:`skin_directions`."""
    vectors = directions.to(rotation_delta.dtype)
    return safe_normalize(vectors + (rotation_delta @ vectors[..., None])[..., 0])


NORMALIZE_EPS = 1e-12
"""Squared-length floor below which :func:`safe_normalize` returns zero (no NaN, no inf)."""


def safe_normalize(vectors: Tensor) -> Tensor:
    """Unit vectors along the last axis; zero-length vectors map to zero with zero gradient."""
    sq = (vectors * vectors).sum(-1, keepdim=True)
    return vectors * torch.rsqrt(sq.clamp_min(NORMALIZE_EPS)) * (sq > NORMALIZE_EPS)
