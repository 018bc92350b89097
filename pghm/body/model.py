"""The body-model interface the rest of pghm uses.

A backend provides the mesh topology (faces, UV faces, texture coordinates), dense skinning
weights, the bone hierarchy with names, and for a shape vector the rest vertices and rest
joint positions, all in the project's world frame (y up, facing +z; see
:mod:`pghm.body.pose`). Posing is shared: :func:`pghm.body.skinning.forward_kinematics`
turns a :class:`~pghm.body.pose.BodyPose` into per-bone 4x4 skinning transforms.

Pose-corrective blend shapes (SMPL-X's ``posedirs``) are deliberately not applied: the
Gaussians live on arbitrary surface points, and the model's pose decoder learns the
pose-dependent offsets those correctives would give.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from pghm.body.pose import BodyPose, PoseError
from pghm.body.skinning import kinematic_levels, lbs, pose_transforms

CANONICAL_JOINTS = (
    "pelvis",
    "spine1",
    "spine2",
    "spine3",
    "neck",
    "head",
    "left_collar",
    "right_collar",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_foot",
    "right_foot",
)
"""Backend-independent names (SMPL's) of the joints that the viewer's sliders, the motion
retargeter and the synthetic data refer to. Each backend maps them to its own bones."""


@dataclass(frozen=True)
class RestBody:
    """A shaped body in its canonical rest pose.

    Attributes:
        vertices: (V, 3) rest vertex positions.
        joints: (J, 3) rest joint (bone head) positions.
    """

    vertices: Tensor
    joints: Tensor


SHAPE_DOMAINS: dict[str, tuple[float, float]] = {"anny": (0.0, 1.0)}
"""The closed range of each body's shape parameters, by body name: Anny's phenotypes are
fractions in [0, 1] (beyond them it clamps, so 1e6 would pass as the tallest body). A body not
listed (SMPL-X: its betas are standard deviations) bounds them only by finiteness."""


def shape_problem(body_name: str, shape: object) -> str | None:
    """Why (S,) ``shape`` cannot be ``body_name``'s shape parameters (a value not finite or outside
    :data:`SHAPE_DOMAINS`), or None; shared by the body models and the file loaders."""
    values = torch.as_tensor(shape, dtype=torch.float64).reshape(-1)
    if not torch.isfinite(values).all():
        return "is not finite"
    if body_name in SHAPE_DOMAINS and values.numel():
        low, high = SHAPE_DOMAINS[body_name]
        outside = (values < low) | (values > high)
        if outside.any():
            first = int(outside.nonzero()[0])
            return (
                f"holds {values[first].item():g} at {first}; the '{body_name}' body's shape parameters "
                f"lie in [{low:g}, {high:g}]"
            )
    return None


class BodyModel(nn.Module):
    """Common interface of the body backends.

    Attributes (set by the backend):
        name: backend name stored in avatar files ("anny", "smplx").
        bone_names: J bone names.
        parents: J parent indices, -1 for the root (bone 0).
        joint_map: canonical joint name (see :data:`CANONICAL_JOINTS`) -> bone index.
        shape_names: S names of the shape parameters.
        faces: (F, 3) long vertex indices of the triangles.
        uv_faces: (F, 3) long indices into ``uv_coords`` of each triangle's corners.
        uv_coords: (T, 2) texture coordinates in [0, 1], v pointing up.
        skin_weights: (V, J) dense skinning weights, rows summing to one.
    """

    name: str
    bone_names: list[str]
    parents: list[int]
    joint_map: dict[str, int]
    shape_names: list[str]

    faces: Tensor
    uv_faces: Tensor
    uv_coords: Tensor
    skin_weights: Tensor

    def _register_topology(self, faces: Tensor, uv_faces: Tensor, uv_coords: Tensor, skin_weights: Tensor) -> None:
        self.register_buffer("faces", faces.long().contiguous(), persistent=False)
        self.register_buffer("uv_faces", uv_faces.long().contiguous(), persistent=False)
        self.register_buffer("uv_coords", uv_coords.float().contiguous(), persistent=False)
        weights = skin_weights.float()
        self.register_buffer("skin_weights", weights / weights.sum(-1, keepdim=True), persistent=False)
        self._levels = kinematic_levels(self.parents)

    @property
    def num_bones(self) -> int:
        return len(self.bone_names)

    @property
    def num_vertices(self) -> int:
        return self.skin_weights.shape[0]

    def default_shape(self) -> Tensor:
        """(S,) the average body's shape parameters."""
        raise NotImplementedError

    def check_shape(self, shape: Tensor | None) -> Tensor:
        """Validate (S,) shape parameters; None gives the default shape."""
        if shape is None:
            return self.default_shape()
        shape = torch.as_tensor(shape, dtype=torch.float32)
        if shape.shape != (len(self.shape_names),):
            raise PoseError(
                f"body shape must be {len(self.shape_names)} values "
                f"({', '.join(self.shape_names)}), got shape {tuple(shape.shape)}"
            )
        problem = shape_problem(self.name, shape)
        if problem is not None:
            raise PoseError(f"body shape {problem}")
        return shape

    def rest(self, shape: Tensor | None = None, dtype: torch.dtype = torch.float32) -> RestBody:
        """Rest vertices and joints for (S,) shape parameters (None: the default body)."""
        raise NotImplementedError

    def bone_transforms(self, pose: BodyPose, joints: Tensor) -> Tensor:
        """(B, J, 4, 4) skinning transforms of ``pose`` for rest ``joints`` (J, 3)."""
        if pose.num_bones != self.num_bones:
            raise PoseError(
                f"pose field 'rotations' has {pose.num_bones} bones, the {self.name} body has {self.num_bones}"
            )
        return pose_transforms(pose, joints, self.parents, self._levels)

    def posed_vertices(self, pose: BodyPose, rest: RestBody) -> Tensor:
        """(B, V, 3) mesh vertices in ``pose``."""
        transforms = self.bone_transforms(pose, rest.joints)
        return lbs(rest.vertices, self.skin_weights, transforms)

    def rest_pose(self, batch_size: int = 1, dtype: torch.dtype = torch.float32) -> BodyPose:
        return BodyPose.rest(self.num_bones, batch_size, dtype)

    def pose_from_arrays(self, rotations: object, translation: object | None = None) -> BodyPose:
        """Validated :class:`BodyPose` from user arrays, (J, 3)/(B, J, 3) and (3,)/(B, 3)."""
        return BodyPose.from_arrays(rotations, translation, self.num_bones)

    def identity_key(self) -> str:
        """A string that changes whenever the topology does (for on-disk caches)."""
        if getattr(self, "_identity_key", None) is None:
            digest = hashlib.sha1()
            for tensor in (self.faces, self.uv_faces, self.uv_coords):
                digest.update(tensor.detach().cpu().numpy().tobytes())
            self._identity_key = f"{self.name}-{digest.hexdigest()[:16]}"
        return self._identity_key
