"""SMPL-X as an optional body, for users who own a model file.

The SMPL-X licence forbids redistribution, so nothing of it ships with pghm: pass your own
``SMPLX_NEUTRAL.npz`` (or ``.pkl``) with ``--body smplx --body-model-path FILE``. The file
is read by the ``smplx`` package (``pip install pghm[smplx]``); its texture coordinates
(``vt``, ``ft``, present in the official npz files) come from the same file. SMPL-X files
are pickles: only open model files you trust.

SMPL-X is natively y up and facing +z, the project frame. Its 55 joints are body (22),
jaw, two eyes and 2 x 15 finger joints; betas (10 by default) are the shape parameters.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pghm.body.model import CANONICAL_JOINTS, BodyModel, RestBody
from pghm.errors import PghmError

SMPLX_NUM_JOINTS = 55
"""Body, jaw, eyes and hands; the extra vertex-based keypoints of the smplx package are
landmarks, not bones."""

DEFAULT_NUM_BETAS = 10


def _read_uv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The ``vt`` (T, 2) and ``ft`` (F, 3) arrays of an SMPL-X model file."""
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as data:
            if "vt" not in data or "ft" not in data:
                raise PghmError(f"{path}: no texture coordinates ('vt', 'ft') in the model file")
            return np.asarray(data["vt"]), np.asarray(data["ft"])
    with open(path, "rb") as file:
        data = pickle.load(file, encoding="latin1")
    if "vt" not in data or "ft" not in data:
        raise PghmError(f"{path}: no texture coordinates ('vt', 'ft') in the model file")
    return np.asarray(data["vt"]), np.asarray(data["ft"])


class SMPLXBody(BodyModel):
    """SMPL-X behind the :class:`~pghm.body.model.BodyModel` interface."""

    def __init__(self, model_path: str | Path, num_betas: int = DEFAULT_NUM_BETAS) -> None:
        super().__init__()
        try:
            import smplx
            from smplx.joint_names import JOINT_NAMES
        except ImportError:
            raise PghmError("the SMPL-X body needs the smplx package: pip install 'pghm[smplx]'") from None
        path = Path(model_path)
        if not path.is_file():
            raise PghmError(f"{path}: SMPL-X model file not found")
        try:
            layer = smplx.SMPLX(str(path), ext=path.suffix.lstrip("."), num_betas=num_betas, use_pca=False)
        except Exception as error:  # noqa: BLE001 - smplx raises many types on a foreign file
            raise PghmError(f"{path}: not a readable SMPL-X model file ({type(error).__name__}: {error})") from None
        vt, ft = _read_uv(path)
        self.name = "smplx"
        self.bone_names = list(JOINT_NAMES[:SMPLX_NUM_JOINTS])
        self.parents = [int(p) for p in layer.parents]
        self.joint_map = {name: self.bone_names.index(name) for name in CANONICAL_JOINTS}
        self.shape_names = [f"beta{i}" for i in range(layer.num_betas)]
        self.register_buffer("v_template", layer.v_template.float(), persistent=False)
        self.register_buffer("shapedirs", layer.shapedirs.float(), persistent=False)
        self.register_buffer("j_regressor", layer.J_regressor.float(), persistent=False)
        uv = torch.as_tensor(vt, dtype=torch.float32)
        self._register_topology(
            faces=layer.faces_tensor,
            uv_faces=torch.as_tensor(ft.astype(np.int64)),
            uv_coords=uv,
            skin_weights=layer.lbs_weights,
        )

    def default_shape(self) -> Tensor:
        return torch.zeros(len(self.shape_names))

    def rest(self, shape: Tensor | None = None, dtype: torch.dtype = torch.float32) -> RestBody:
        betas = self.check_shape(shape).to(dtype)
        # v[v, k] = T[v, k] + sum_l betas[l] S[v, k, l]
        vertices = self.v_template.to(dtype) + torch.einsum("l,vkl->vk", betas, self.shapedirs.to(dtype))
        # J[j, k] = sum_v R[j, v] v[v, k]
        joints = self.j_regressor.to(dtype) @ vertices
        return RestBody(vertices, joints)
