"""Optional approximations of the splatter, all off by default (the default is the exact spec)."""

from __future__ import annotations

from dataclasses import dataclass

from pghm.errors import PghmError
from pghm.splat.spec import ALPHA_MAX, ALPHA_MIN


@dataclass(frozen=True)
class SplatSettings:
    """Speed/accuracy trade-offs; ``pghm bench splat`` measures each one against the exact image."""

    alpha_cutoff: float = ALPHA_MIN
    """Pairs with alpha below this are skipped. The spec is 1/255; raising it shrinks every footprint."""

    transmittance_stop: float = 0.0
    """A pixel stops compositing once its transmittance T falls below this (3DGS uses 1e-4); 0 never stops."""

    footprint_sigmas: float | None = None
    """Clip each footprint to a square of half-side this many sqrt(lambda_max(cov2d)) (3DGS: 3); None: exact."""

    half_precision_depth: bool = False
    """Sort on float16 depth keys; near-equal depths may then composite out of order."""

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha_cutoff < ALPHA_MAX:
            raise PghmError(f"splat settings: alpha_cutoff must be in (0, {ALPHA_MAX}), got {self.alpha_cutoff}")
        if not 0.0 <= self.transmittance_stop < 1.0:
            raise PghmError(f"splat settings: transmittance_stop must be in [0, 1), got {self.transmittance_stop}")
        if self.footprint_sigmas is not None and not self.footprint_sigmas > 0:
            raise PghmError(f"splat settings: footprint_sigmas must be positive, got {self.footprint_sigmas}")

    @property
    def is_exact(self) -> bool:
        return self == SplatSettings()
