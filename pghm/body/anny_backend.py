"""The default body: Anny (Apache-2.0 code, CC0 MakeHuman assets inside the wheel).

``anny.Anny(skinning_method="lbs")`` gives 13,718 vertices, 27,420 triangles, 104 bones
and 6 phenotype parameters. Its native frame is z up with the body facing -y; vertices and
joints are rotated into the project frame (y up, facing +z) on the way out. Its rest pose
is an A-pose, which serves as the paper's canonical neutral pose.

The first construction on a machine parses the MakeHuman assets (about a minute and a
half, ~790 MB written to ``~/.cache/anny`` or ``$ANNY_CACHE_DIR``); later ones take ~20 ms.
"""

from __future__ import annotations

import sys

import torch
from torch import Tensor

from pghm.body.model import BodyModel, RestBody

ANNY_TO_WORLD = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Rotation taking Anny's frame (z up, facing -y) to the project's (y up, facing +z)."""

ANNY_JOINT_MAP = {
    "pelvis": "root",
    "spine1": "spine05",
    "spine2": "spine03",
    "spine3": "spine01",
    "neck": "neck01",
    "head": "head",
    "left_collar": "clavicle.L",
    "right_collar": "clavicle.R",
    "left_shoulder": "upperarm01.L",
    "right_shoulder": "upperarm01.R",
    "left_elbow": "lowerarm01.L",
    "right_elbow": "lowerarm01.R",
    "left_wrist": "wrist.L",
    "right_wrist": "wrist.R",
    "left_hip": "upperleg01.L",
    "right_hip": "upperleg01.R",
    "left_knee": "lowerleg01.L",
    "right_knee": "lowerleg01.R",
    "left_ankle": "foot.L",
    "right_ankle": "foot.R",
}
"""Canonical joint -> Anny bone. Anny's limbs carry twist segments (``upperarm02``,
``lowerarm02``, ...) that stay at rest; its feet end in five toe chains instead of one
``foot`` joint, so ``left_foot``/``right_foot`` are not mapped."""

DEFAULT_PHENOTYPE = 0.5
"""Anny's phenotype parameters lie in [0, 1]; 0.5 is its average adult."""


def _build_anny():
    import anny
    import anny.paths

    cache = anny.paths.get_anny_cache_path()
    if not cache.exists() or not any(cache.iterdir()):
        print(
            f"pghm: building the Anny body model assets into {cache} (first run only, about 90 s)...",
            file=sys.stderr,
        )
    return anny.Anny(skinning_method="lbs")


class AnnyBody(BodyModel):
    """Anny behind the :class:`~pghm.body.model.BodyModel` interface."""

    def __init__(self) -> None:
        super().__init__()
        self.name = "anny"
        self._anny = _build_anny()
        self.bone_names = list(self._anny.bone_labels)
        self.parents = [int(p) for p in self._anny.bone_parents]
        self.joint_map = {k: self.bone_names.index(v) for k, v in ANNY_JOINT_MAP.items()}
        self.shape_names = list(self._anny.phenotype_labels)
        self._register_topology(
            faces=self._anny.faces,
            uv_faces=self._anny.face_texture_coordinate_indices,
            uv_coords=self._anny.texture_coordinates,
            skin_weights=self._anny.dense_vertex_bone_weights,
        )

    def default_shape(self) -> Tensor:
        return torch.full((len(self.shape_names),), DEFAULT_PHENOTYPE)

    def rest(self, shape: Tensor | None = None, dtype: torch.dtype = torch.float32) -> RestBody:
        shape = self.check_shape(shape)
        out = self._anny(phenotype_kwargs=shape[None].to(self._anny.dtype))
        to_world = ANNY_TO_WORLD.to(self._anny.dtype)
        vertices = out["rest_vertices"][0] @ to_world.T
        joints = out["rest_bone_heads"][0] @ to_world.T
        return RestBody(vertices.to(dtype), joints.to(dtype))
