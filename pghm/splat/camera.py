"""Pinhole cameras for the splatter, in OpenCV axes: x right, y down, z forward.

A camera maps a world point X to camera space t = R X + T (``world_to_camera`` = [R T; 0 1])
and to the pixel (u, v) = (fx t_x / t_z + cx, fy t_y / t_z + cy); pixel (row i, column j)
has its centre at (j + 0.5, i + 0.5). One :class:`Camera` holds one view or a batch of B
views sharing an image size; intrinsics may be floats or (B,) tensors.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from pghm.errors import PghmError

RIGID_ROW_TOLERANCE = 1e-4
"""How far the bottom row of ``world_to_camera`` may be from (0, 0, 0, 1). Loose: the projection
ignores that row; the check only catches transposed or projective matrices."""

Scalar = float | Tensor


def _batch_of(value: Scalar, name: str) -> int | None:
    """The batch size B of an intrinsic (None for a plain number); raises on other shapes."""
    if isinstance(value, Tensor):
        if value.dim() == 0:
            return None
        if value.dim() != 1:
            raise PghmError(f"camera: {name} must be a number or a (B,) tensor, got shape {tuple(value.shape)}")
        return value.shape[0]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PghmError(f"camera: {name} must be a number or a (B,) tensor, got {type(value).__name__}")
    return None


def _as_double(value: Scalar) -> Tensor:
    if isinstance(value, Tensor):
        return value.detach().to(torch.float64)
    return torch.tensor(float(value), dtype=torch.float64)


INTRINSICS = ("fx", "fy", "cx", "cy")


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera, or a batch of B of them with one image size.

    Attributes:
        fx: focal length along x in pixels; float or (B,) tensor.
        fy: focal length along y in pixels; float or (B,) tensor.
        cx: principal point x in pixels; float or (B,) tensor.
        cy: principal point y in pixels; float or (B,) tensor.
        width: image width W in pixels.
        height: image height H in pixels.
        world_to_camera: (4, 4) or (B, 4, 4) transform [R T; 0 1]; may require grad.
    """

    fx: Scalar
    fy: Scalar
    cx: Scalar
    cy: Scalar
    width: int
    height: int
    world_to_camera: Tensor

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            size = getattr(self, name)
            if isinstance(size, bool) or not isinstance(size, int) or size <= 0:
                raise PghmError(f"camera: {name} must be a positive integer, got {size!r}")
        batch_sizes = {name: _batch_of(getattr(self, name), name) for name in ("fx", "fy", "cx", "cy")}
        for name in ("fx", "fy", "cx", "cy"):
            value = _as_double(getattr(self, name))
            if not bool(torch.isfinite(value).all()):
                raise PghmError(f"camera: {name} must be finite")
            if name in ("fx", "fy") and not bool((value > 0).all()):
                raise PghmError(f"camera: {name} must be positive")
        pose = self.world_to_camera
        if not isinstance(pose, Tensor) or not pose.is_floating_point():
            raise PghmError("camera: world_to_camera must be a floating-point tensor")
        if pose.shape[-2:] != (4, 4) or pose.dim() not in (2, 3):
            raise PghmError(f"camera: world_to_camera must be (4, 4) or (B, 4, 4), got {tuple(pose.shape)}")
        pose = pose.detach().to(torch.float64)
        if not bool(torch.isfinite(pose).all()):
            raise PghmError("camera: world_to_camera must be finite")
        bottom = pose.new_tensor([0.0, 0.0, 0.0, 1.0])
        if not bool(((pose[..., 3, :] - bottom).abs() <= RIGID_ROW_TOLERANCE).all()):
            raise PghmError("camera: world_to_camera's bottom row must be (0, 0, 0, 1)")
        batch_sizes["world_to_camera"] = pose.shape[0] if pose.dim() == 3 else None
        sizes = {size for size in batch_sizes.values() if size is not None}
        if len(sizes) > 1:
            raise PghmError(f"camera: batch sizes disagree: {batch_sizes}")

    @property
    def batch_size(self) -> int | None:
        """B for a batch of cameras, None for a single one."""
        for value in (self.world_to_camera, self.fx, self.fy, self.cx, self.cy):
            if isinstance(value, Tensor) and value.dim() in (1, 3):
                return value.shape[0]
        return None

    def intrinsics(self, batch: int = 1) -> Tensor:
        """(B, 4) float64 [fx, fy, cx, cy], broadcast to ``batch`` rows for a single camera."""
        rows = self.batch_size or batch
        columns = [_as_double(getattr(self, name)).expand(rows) for name in ("fx", "fy", "cx", "cy")]
        return torch.stack(columns, dim=-1)

    @property
    def K(self) -> Tensor:  # noqa: N802 - the conventional name of the intrinsic matrix
        """(3, 3) or (B, 3, 3) float64 intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]."""
        fx, fy, cx, cy = self.intrinsics().unbind(-1)
        zero, one = torch.zeros_like(fx), torch.ones_like(fx)
        matrix = torch.stack([fx, zero, cx, zero, fy, cy, zero, zero, one], dim=-1).reshape(-1, 3, 3)
        return matrix if self.batch_size else matrix[0]

    @property
    def centre(self) -> Tensor:
        """(3,) or (B, 3) camera position in world space, -R^T T."""
        rotation = self.world_to_camera[..., :3, :3]
        translation = self.world_to_camera[..., :3, 3]
        return -(rotation.transpose(-1, -2) @ translation.unsqueeze(-1)).squeeze(-1)

    @classmethod
    def stack(cls, cameras: list[Camera], dtype: torch.dtype = torch.float32) -> Camera:
        """A batch of the single ``cameras`` (one image size), their values in ``dtype``.

        The cameras were checked when they were made, so their stack is not checked again: on a
        CUDA device each check reads a value to the host, which waits for the device.
        """
        if not cameras or any(c.batch_size is not None for c in cameras):
            raise PghmError("camera: stack takes one or more single cameras")
        if len({(c.width, c.height) for c in cameras}) > 1:
            raise PghmError("camera: a batch of cameras needs one image size")
        batch = object.__new__(cls)
        values = {name: torch.stack([_as_double(getattr(c, name)) for c in cameras]).to(dtype) for name in INTRINSICS}
        values["world_to_camera"] = torch.stack([c.world_to_camera for c in cameras]).to(dtype)
        for name, value in {**values, "width": cameras[0].width, "height": cameras[0].height}.items():
            object.__setattr__(batch, name, value)
        return batch

    @classmethod
    def from_matrices(cls, K: Tensor, world_to_camera: Tensor, width: int, height: int) -> Camera:  # noqa: N803
        """A camera from an intrinsic matrix K (3, 3) or (B, 3, 3) and an extrinsic (4, 4) or (B, 4, 4)."""
        if not isinstance(K, Tensor) or K.shape[-2:] != (3, 3) or K.dim() not in (2, 3):
            raise PghmError(f"camera: K must be a (3, 3) or (B, 3, 3) tensor, got {getattr(K, 'shape', K)!r}")
        if bool((K[..., 0, 1] != 0).any()):
            raise PghmError("camera: K must have zero skew")
        return cls(K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2], width, height, world_to_camera)

    @classmethod
    def look_at(
        cls,
        eye: Sequence[float] | Tensor,
        target: Sequence[float] | Tensor,
        up: Sequence[float] | Tensor = (0.0, 1.0, 0.0),
        fov_y_degrees: float = 40.0,
        width: int = 256,
        height: int = 256,
    ) -> Camera:
        """A camera at ``eye`` looking at ``target``, ``up`` pointing to the top of the image.

        Square pixels, principal point at the image centre, fy = (H / 2) / tan(fov_y / 2).
        """
        if not 0.0 < fov_y_degrees < 180.0:
            raise PghmError(f"camera: fov_y_degrees must be in (0, 180), got {fov_y_degrees}")
        eye, target, up = (torch.as_tensor(v, dtype=torch.float64).reshape(3) for v in (eye, target, up))
        forward = target - eye
        right = torch.linalg.cross(forward, up)
        if forward.norm() == 0 or right.norm() <= 1e-9 * forward.norm() * up.norm():
            raise PghmError("camera: look_at needs eye != target and up not parallel to the view direction")
        forward = forward / forward.norm()
        right = right / right.norm()
        down = torch.linalg.cross(forward, right)  # completes the right-handed frame x right, y down, z forward
        world_to_camera = torch.eye(4, dtype=torch.float64)
        world_to_camera[:3, :3] = torch.stack([right, down, forward])
        world_to_camera[:3, 3] = -world_to_camera[:3, :3] @ eye
        focal = 0.5 * height / math.tan(math.radians(fov_y_degrees) / 2)
        return cls(focal, focal, width / 2, height / 2, width, height, world_to_camera.float())
