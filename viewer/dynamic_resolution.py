"""Dynamic resolution: while the view moves, the internal resolution that holds the frame budget.

The sprite pass is fragment-bound (docs/gl.md): its time grows with the pixel count, about
t(s) = t(1) s^2 at internal scale s (fraction of the viewport per side). After a frame drawn
at scale s in t ms, the scale that would take the budget B is

    s* = s sqrt(B / t)

and the controller moves there smoothly in log space (a single slow frame, e.g. another
process taking the cores, should not halve the resolution) and rounds to steps of
``SCALE_STEP`` (each new size reallocates the accumulation target). Once the view stops,
the viewer draws at scale 1, the exact image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from pghm.errors import PghmError

SCALE_STEP = 0.05
"""The internal scale is a multiple of this."""


@dataclass
class ResolutionSettings:
    """Budget and bounds of the dynamic resolution (a setting of the viewer)."""

    draw_budget_ms: float = 5.0
    """Scene draw time to hold while moving: the rest of a 16 ms frame is the UI, the depth sort
    and copies (measured on a quiet machine: 10 ms gave orbit frames of p95 27.9 ms, 5 ms 25.0 ms)."""
    min_scale: float = 0.25
    """Never below this fraction of the viewport per side."""
    smoothing: float = 0.5
    """Weight of the previous scale in log space (0: jump to the estimate)."""
    settle_seconds: float = 0.15
    """After the view and the pose stop for this long, the exact full-resolution frame is drawn."""
    moving_precision: Literal["float", "double"] = "float"
    """The sprites' projection while moving: float32 costs less per Gaussian on llvmpipe (at the
    least scale the vertex work, not the pixels, is most of the draw) and its rare cut-off flips
    (max 2.4e-3) are far below the reduced resolution's error; the settled frame uses the renderer's."""
    moving_cull_degrees: float | None = 30.0
    """Back-face culling while moving (None: off): the sprites facing the order view, with this margin
    in degrees past the silhouette (:func:`pghm.gl.cull.facing`), enter the depth order and the pass;
    the settled frame draws every Gaussian."""

    def __post_init__(self) -> None:
        if self.draw_budget_ms <= 0:
            raise PghmError(f"draw budget must be positive, got {self.draw_budget_ms} ms")
        if not 0 < self.min_scale <= 1:
            raise PghmError(f"minimum scale must be in (0, 1], got {self.min_scale}")
        if self.moving_precision not in ("float", "double"):
            raise PghmError(f"moving precision must be 'float' or 'double', got {self.moving_precision!r}")
        if self.moving_cull_degrees is not None and not 0 <= self.moving_cull_degrees <= 90:
            raise PghmError(f"moving cull margin must be in [0, 90] degrees, got {self.moving_cull_degrees}")


class ResolutionController:
    """The internal scale for moving frames, updated from each moving frame's measured draw time."""

    def __init__(self, settings: ResolutionSettings | None = None) -> None:
        self.settings = settings or ResolutionSettings()
        self._scale = 1.0

    @property
    def scale(self) -> float:
        """The scale to draw the next moving frame at (a multiple of SCALE_STEP in [min_scale, 1])."""
        return self._scale

    def update(self, scale: float, draw_ms: float, moving: bool = True) -> float:
        """Record that a frame at ``scale`` took ``draw_ms``; returns the next scale.

        A still frame (``moving=False``, drawn at full scale) may only lower the scale. Its
        estimate s* = s sqrt(B / t) bounds the moving scale from above: with a fixed per-sprite
        cost a besides the pixels', t(s) = a + b s^2, the scale that takes B is
        sqrt((B - a) / b) <= sqrt(B / (a + b)) whenever the still frame is over budget. Letting
        it raise the scale made each orbit start at 0.35-0.45 after a settled frame (first
        moving frames 19-28 ms against 12-14 at the moving scale 0.25; the p95's frames).
        """
        settings = self.settings
        target = scale * math.sqrt(settings.draw_budget_ms / max(draw_ms, 1e-3))
        if moving:
            target = math.exp(settings.smoothing * math.log(self._scale) + (1 - settings.smoothing) * math.log(target))
        stepped = min(1.0, max(settings.min_scale, round(target / SCALE_STEP) * SCALE_STEP))
        self._scale = stepped if moving else min(self._scale, stepped)
        return self._scale
