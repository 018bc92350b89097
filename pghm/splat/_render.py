"""``render``: validates, moves the Gaussians to camera space, projects them, and hands them to a rasteriser.

CPU tensors go to the CPU splatter (native kernel or torch twin), CUDA tensors to gsplat
(:mod:`pghm.splat.gsplat_backend`): the device of the inputs picks the path."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from pghm.errors import PghmError
from pghm.splat import _torch_impl
from pghm.splat._projection import footprints, project, to_camera
from pghm.splat._settings import SplatSettings
from pghm.splat.camera import Camera
from pghm.splat.gsplat_backend import render_gsplat

Backend = Literal["auto", "native", "torch", "gsplat"]
BACKENDS: tuple[str, ...] = ("auto", "native", "torch", "gsplat")
CPU_BACKENDS: tuple[str, ...] = ("native", "torch")
"""Backends that render CPU tensors; "gsplat" renders CUDA tensors."""


@dataclass(frozen=True)
class RenderOutput:
    """One image per camera; the leading B is absent when neither Gaussians nor camera are batched.

    Attributes:
        rgb: (B, H, W, 3) composited colour, background included.
        alpha: (B, H, W) accumulated opacity 1 - T_N.
        depth: (B, H, W) alpha-weighted view depth sum_i t_z,i alpha_i T_i (not normalised).
    """

    rgb: Tensor
    alpha: Tensor
    depth: Tensor


def _check_gaussians(
    means: Tensor, scales: Tensor, colors: Tensor, opacities: Tensor, check_finite: bool = True
) -> int | None:
    """The Gaussians' batch size (None when unbatched); raises a PghmError naming a bad argument."""
    if not isinstance(means, Tensor) or means.dim() not in (2, 3) or means.shape[-1] != 3:
        got = tuple(means.shape) if isinstance(means, Tensor) else type(means).__name__
        raise PghmError(f"render: means must be an (N, 3) or (B, N, 3) tensor, got {got}")
    if means.device.type not in ("cpu", "cuda"):
        raise PghmError(f"render: tensors on {means.device} cannot be splatted; use the CPU or CUDA")
    leading = tuple(means.shape[:-1])
    expected = {"scales": leading, "colors": (*leading, 3), "opacities": leading}
    for name, value in (("means", means), ("scales", scales), ("colors", colors), ("opacities", opacities)):
        if not isinstance(value, Tensor):
            raise PghmError(f"render: {name} must be a tensor, got {type(value).__name__}")
        if name != "means" and tuple(value.shape) != expected[name]:
            shape = "x".join(map(str, expected[name]))
            raise PghmError(
                f"render: {name} must have shape ({shape}) to match means {tuple(means.shape)}, "
                f"got {tuple(value.shape)}"
            )
        if value.dtype not in (torch.float32, torch.float64):
            raise PghmError(f"render: {name} must be float32 or float64, got {value.dtype}")
        if value.dtype != means.dtype:
            raise PghmError(f"render: {name} is {value.dtype} but means is {means.dtype}; use one dtype")
        if value.device != means.device:
            raise PghmError(f"render: {name} is on {value.device} but means on {means.device}; use one device")
        finite = torch.isfinite(value.detach()) if check_finite else None
        if finite is not None and not bool(finite.all()):
            count = int((~finite).sum())
            raise PghmError(f"render: {name} has {count} non-finite value(s); every Gaussian must be finite")
    return means.shape[0] if means.dim() == 3 else None


def _background(background: Sequence[float] | Tensor, dtype: torch.dtype) -> Tensor:
    """(3,) background in ``dtype``; raises a PghmError unless it is 3 finite numbers."""
    try:
        value = torch.as_tensor(
            background.detach() if isinstance(background, Tensor) else background, dtype=torch.float64
        )
    except (TypeError, ValueError, RuntimeError):
        value = None
    if value is None or value.shape != (3,) or not bool(torch.isfinite(value).all()):
        raise PghmError(f"render: background must be 3 finite numbers, got {background!r}")
    return value.to(dtype)


def _check_backend(backend: str, device: torch.device, settings: SplatSettings) -> None:
    """PghmError unless ``backend`` can render tensors on ``device`` with ``settings``."""
    if backend not in BACKENDS:
        raise PghmError(f"render: backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if device.type == "cpu" and backend == "gsplat":
        raise PghmError("render: backend 'gsplat' renders CUDA tensors; these are on the CPU")
    if device.type == "cpu":
        return
    if backend in CPU_BACKENDS:
        raise PghmError(f"render: CUDA tensors render through gsplat (backend 'auto' or 'gsplat'), not {backend!r}")
    if not settings.is_exact:
        raise PghmError("render: SplatSettings apply to the CPU splatter; gsplat has its own fixed approximations")


def _rasteriser(backend: str):
    if backend == "torch":
        return _torch_impl.rasterize
    # Imported here, not at the top, so that `python -m pghm.splat.native` (the pre-build step)
    # runs the module once rather than finding it already imported by the package.
    from pghm.splat import native

    if backend == "native":
        native.load_extension()
        return native.rasterize
    if native.is_available():
        return native.rasterize
    _warn_fallback()
    return _torch_impl.rasterize


_warned = False


def _warn_fallback() -> None:
    """Warn once per process that the native kernel did not build and the torch twin is used."""
    from pghm.splat import native

    global _warned
    if _warned:
        return
    _warned = True
    try:
        native.load_extension()
    except PghmError as error:
        message = f"pghm.splat: {error}; rendering with the much slower pure-PyTorch path"
        warnings.warn(message, RuntimeWarning, stacklevel=4)


def render(
    means: Tensor,
    scales: Tensor,
    colors: Tensor,
    opacities: Tensor,
    camera: Camera,
    background: Sequence[float] | Tensor = (1.0, 1.0, 1.0),
    *,
    settings: SplatSettings | None = None,
    backend: Backend = "auto",
    check_finite: bool = True,
) -> RenderOutput:
    """Splat isotropic Gaussians into one image per camera, by the spec in :mod:`pghm.splat`.

    Args:
        means: (N, 3) or (B, N, 3) world positions mu.
        scales: (N,) or (B, N) isotropic world standard deviations s.
        colors: (N, 3) or (B, N, 3) colours c.
        opacities: (N,) or (B, N) opacities o.
        camera: one camera, or a batch of B (Gaussians and cameras broadcast over B).
        background: (3,) colour behind everything, a tuple or tensor (no gradient).
        settings: approximations to switch on; None is the exact spec.
        backend: "native" (C++ kernel), "torch" (readable twin) or "auto" (native if it builds)
            for CPU tensors; "gsplat" or "auto" for CUDA tensors (:mod:`pghm.splat.gsplat_backend`,
            float32, with the differences to this spec listed there).
        check_finite: False skips the check that every value is finite, for a caller that has
            made them so (the training loop); on a CUDA device the check waits for the device.

    Returns:
        rgb (B, H, W, 3), alpha (B, H, W), depth (B, H, W) in the Gaussians' dtype, with B
        dropped when neither the Gaussians nor the camera are batched. Differentiable with
        respect to the Gaussians and ``camera.world_to_camera``.
    """
    if not isinstance(camera, Camera):
        raise PghmError(f"render: camera must be a pghm.splat.Camera, got {type(camera).__name__}")
    settings = settings if settings is not None else SplatSettings()
    gaussian_batch = _check_gaussians(means, scales, colors, opacities, check_finite)
    camera_batch = camera.batch_size
    if gaussian_batch is not None and camera_batch is not None and gaussian_batch != camera_batch:
        raise PghmError(f"render: {gaussian_batch} batched Gaussian sets but {camera_batch} cameras")
    batch = gaussian_batch or camera_batch or 1
    _check_backend(backend, means.device, settings)

    means, scales, colors, opacities = (
        value.expand(batch, *value.shape[-dims:]) if gaussian_batch is None else value
        for value, dims in ((means, 2), (scales, 1), (colors, 2), (opacities, 1))
    )
    if means.device.type == "cpu":
        rasterize = _rasteriser(backend)
        rgb, alpha, depth = _render_cpu(means, scales, colors, opacities, camera, background, settings, rasterize)
    else:
        rgb, alpha, depth = render_gsplat(
            means, scales, colors, opacities, camera, _background(background, colors.dtype)
        )
    if gaussian_batch is None and camera_batch is None:
        rgb, alpha, depth = rgb[0], alpha[0], depth[0]
    return RenderOutput(rgb=rgb, alpha=alpha, depth=depth)


def _render_cpu(
    means: Tensor,
    scales: Tensor,
    colors: Tensor,
    opacities: Tensor,
    camera: Camera,
    background: Sequence[float] | Tensor,
    settings: SplatSettings,
    rasterize: Callable[..., tuple[Tensor, Tensor, Tensor]],
) -> tuple[Tensor, Tensor, Tensor]:
    """rgb (B, H, W, 3), alpha (B, H, W), depth (B, H, W) of (B, N, ...) Gaussians by the CPU splatter."""
    batch = means.shape[0]
    pose = camera.world_to_camera.to(means.device).expand(batch, 4, 4)
    projection = project(to_camera(means, pose), scales, camera.intrinsics(batch), camera.width, camera.height)
    prints = footprints(projection, opacities, camera.width, camera.height, settings)
    return rasterize(
        projection.means2d,
        projection.conics,
        colors,
        opacities,
        projection.depths.to(colors.dtype),
        _background(background, colors.dtype),
        prints,
        camera.width,
        camera.height,
        settings,
    )
