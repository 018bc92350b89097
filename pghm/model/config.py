"""Model configuration: every size is a value here, with defaults for a 2-core CPU.

Scaling up on real hardware means changing these values (e.g. ``uv_resolution=256``,
``latent_channels=32``, wider ``encoder_channels``), not code.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Literal

from pghm.errors import PghmError
from pghm.model.detail import DETAIL_FACTOR
from pghm.uv.atlas import MAX_RESOLUTION, check_resolution

MAX_CHANNELS = 4096
"""Largest channel count accepted: far above any sensible width, low enough that a corrupted
config cannot ask for terabytes."""


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclass(frozen=True)
class ModelConfig:
    """Sizes and bounds of the PGHM network."""

    uv_resolution: int = 128
    """L: side of the UV maps; every valid texel is one Gaussian (11,156 at 128 for Anny)."""

    latent_channels: int = 16
    """C: channels of the identity map F (and of the latents in the bank)."""

    encoder_channels: tuple[int, ...] = (24, 32, 48, 64, 96)
    """Channels of the U-Net encoder E_u at resolutions L, L/2, L/4, ...; the last is the bottleneck."""

    decoder_channels: tuple[int, ...] = (64, 48, 32, 16)
    """Channels of each decoder head on the way up, from the bottleneck's parent level to L."""

    condition_channels: tuple[int, ...] = (8, 12, 16, 24, 32)
    """Channels of the light pose and view encoders E_p, E_v at each encoder level."""

    head: Literal["multi", "single"] = "multi"
    """"multi": the paper's D_static, D_pose, D_view; "single": one decoder for everything (ablation)."""

    max_static_offset: float = 0.12
    """Bound (metres) on the static position offset V_p (loose clothes, hair)."""

    max_pose_offset: float = 0.04
    """Bound (metres) on the pose-dependent position offset V_p^o (wrinkles, folds)."""

    scale_factor_range: float = 4.0
    """The isotropic scale stays within [1/r, r] times the texel's base scale."""

    base_scale_factor: float = 0.6
    """Base scale = this x the surface length one texel spans at that texel."""

    min_scale: float = 5e-4
    max_scale: float = 0.05
    """Absolute bounds (metres) on every Gaussian's scale."""

    detail: bool = False
    """Place the Gaussians on a 2L atlas with per-texel colour, scale and lift residuals trained directly
    (:mod:`pghm.model.detail`); False: the paper's model, one Gaussian per L texel."""

    max_detail_offset: float = 0.01
    """Bound (metres) on the detail layer's lift of a Gaussian along the surface normal (cloth
    folds, the edges of clothes: a few millimetres)."""

    def __post_init__(self) -> None:
        check_resolution(self.uv_resolution)
        for name in ("latent_channels", "encoder_channels", "decoder_channels", "condition_channels"):
            value = getattr(self, name)
            counts = (value,) if name == "latent_channels" else value
            if not isinstance(counts, tuple) or not all(_is_int(c) and 1 <= c <= MAX_CHANNELS for c in counts):
                raise PghmError(f"model config: {name} must be whole numbers from 1 to {MAX_CHANNELS}, got {value!r}")
        for name, low, high in _BOUNDS:
            value = getattr(self, name)
            if not (_is_real(value) and math.isfinite(value) and low <= value <= high):
                raise PghmError(f"model config: {name} must be a number in [{low:g}, {high:g}], got {value!r}")
        if self.min_scale > self.max_scale:
            raise PghmError(f"model config: min_scale {self.min_scale} is larger than max_scale {self.max_scale}")
        levels = len(self.encoder_channels)
        if len(self.decoder_channels) != levels - 1 or len(self.condition_channels) != levels:
            raise PghmError(
                "model config: decoder_channels needs one entry fewer than encoder_channels, condition_channels as many"
            )
        if self.uv_resolution >> (levels - 1) < 4:
            raise PghmError(f"model config: {levels} levels are too many for L = {self.uv_resolution}")
        if type(self.detail) is not bool:
            raise PghmError(f"model config: detail must be true or false, got {self.detail!r}")
        if self.detail and DETAIL_FACTOR * self.uv_resolution > MAX_RESOLUTION:
            raise PghmError(
                f"model config: a detail layer needs {DETAIL_FACTOR}L <= {MAX_RESOLUTION}, L is {self.uv_resolution}"
            )
        if self.head not in ("multi", "single"):
            raise PghmError(f"model config: head must be 'multi' or 'single', got {self.head!r}")

    @property
    def latent_resolution(self) -> int:
        """L' = L / 2: side of the compact latents of the identity bank."""
        return self.uv_resolution // 2

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(values: dict) -> ModelConfig:
        if not isinstance(values, dict):
            raise PghmError(f"model config: expected a mapping of fields, got {type(values).__name__}")
        known = {f.name for f in fields(ModelConfig)}
        unknown = set(values) - known
        if unknown:
            raise PghmError(f"model config: unknown fields {sorted(unknown)}")
        converted = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
        return ModelConfig(**converted)


_BOUNDS = (
    ("max_static_offset", 0.0, 10.0),
    ("max_pose_offset", 0.0, 10.0),
    ("max_detail_offset", 0.0, 10.0),
    ("scale_factor_range", 1.0, 1e6),
    ("base_scale_factor", 1e-6, 1e3),
    ("min_scale", 1e-9, 10.0),
    ("max_scale", 1e-9, 10.0),
)
"""(field, lowest, highest) of the float fields: finite, and where the model's formulas stay
finite (ln r needs r >= 1; a scale must be positive)."""
