"""The pose representation every part of pghm shares.

A pose is, for each bone j of the body model, an axis-angle rotation ``rotations[j]``
(radians, right-handed) about the bone's head, expressed in *rest-aligned* axes: the
world axes of the canonical rest pose, as in SMPL. The root bone's rotation is the global
orientation; ``translation`` moves the root in metres. The all-zero pose is the body's
canonical rest pose (an A-pose for Anny, a T-pose for SMPL-X).

World frame: y up, the body facing +z, its left side towards +x (the SMPL convention);
backends whose native frame differs are converted on load.

The viewer's sliders, motion files (``.npz``), datasets (``poses.npz``) and training all
use exactly these two arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from pghm.errors import PghmError


class PoseError(PghmError):
    """A pose array with the wrong shape or non-finite values."""


def _as_float_tensor(name: str, value: object, dtype: torch.dtype | None) -> Tensor:
    try:
        tensor = torch.as_tensor(value)
    except (TypeError, ValueError, RuntimeError) as error:
        raise PoseError(f"pose field '{name}' is not a numeric array: {error}") from None
    if not (tensor.is_floating_point() or tensor.dtype in (torch.int32, torch.int64)):
        raise PoseError(f"pose field '{name}' has dtype {tensor.dtype}, expected a float array")
    return tensor.to(dtype or (tensor.dtype if tensor.is_floating_point() else torch.float32))


@dataclass(frozen=True)
class BodyPose:
    """A batch of poses.

    Attributes:
        rotations: (B, J, 3) axis-angle per bone, rest-aligned axes, radians.
        translation: (B, 3) root translation in metres.
    """

    rotations: Tensor
    translation: Tensor

    @property
    def batch_size(self) -> int:
        return self.rotations.shape[0]

    @property
    def num_bones(self) -> int:
        return self.rotations.shape[1]

    @staticmethod
    def rest(num_bones: int, batch_size: int = 1, dtype: torch.dtype = torch.float32) -> BodyPose:
        """The canonical rest pose, (B, J, 3) zeros and (B, 3) zeros."""
        return BodyPose(
            torch.zeros(batch_size, num_bones, 3, dtype=dtype),
            torch.zeros(batch_size, 3, dtype=dtype),
        )

    @staticmethod
    def from_arrays(
        rotations: object,
        translation: object | None,
        num_bones: int,
        dtype: torch.dtype | None = None,
    ) -> BodyPose:
        """Validate user arrays into a batched pose.

        Accepts ``rotations`` as (J, 3) or (B, J, 3) and ``translation`` as (3,), (B, 3)
        or None (zeros). Raises :class:`PoseError` (a ``ValueError``) naming the field
        for a wrong shape or a non-finite value.
        """
        rot = _as_float_tensor("rotations", rotations, dtype)
        if rot.ndim == 2:
            rot = rot[None]
        if rot.ndim != 3 or rot.shape[1:] != (num_bones, 3):
            raise PoseError(
                f"pose field 'rotations' has shape {tuple(rot.shape)}, expected ({num_bones}, 3) or (B, {num_bones}, 3)"
            )
        if translation is None:
            trans = torch.zeros(rot.shape[0], 3, dtype=rot.dtype, device=rot.device)
        else:
            trans = _as_float_tensor("translation", translation, rot.dtype)
            if trans.ndim == 1:
                trans = trans[None]
            if trans.ndim != 2 or trans.shape[1] != 3 or trans.shape[0] not in (1, rot.shape[0]):
                raise PoseError(
                    f"pose field 'translation' has shape {tuple(trans.shape)}, expected (3,) or ({rot.shape[0]}, 3)"
                )
            trans = trans.expand(rot.shape[0], 3)
        for name, tensor in (("rotations", rot), ("translation", trans)):
            if not torch.isfinite(tensor).all():
                bad = (~torch.isfinite(tensor)).nonzero()[0].tolist()
                raise PoseError(f"pose field '{name}' has a non-finite value at index {bad}")
        return BodyPose(rot, trans)

    def to(self, dtype: torch.dtype) -> BodyPose:
        return BodyPose(self.rotations.to(dtype), self.translation.to(dtype))

    def __getitem__(self, index: int | slice) -> BodyPose:
        if isinstance(index, int):
            index = slice(index, index + 1)
        return BodyPose(self.rotations[index], self.translation[index])
