"""The splatting specification's constants (steps 2, 4 and 5 of :mod:`pghm.splat`).

One definition, read by every renderer that must agree with the spec: the CPU splatter
(:mod:`pghm.splat`), the GL renderer (:mod:`pghm.gl`, which passes them to the GLSL sources
as ``#define`` lines through :func:`shaders.source`) and the benchmarks.
"""

NEAR_PLANE = 0.01
"""Gaussians with camera-space depth t_z at or below this are dropped (world units)."""

COV_DILATION = 0.3
"""Added to the screen covariance's diagonal (px^2): every splat covers about a pixel (3DGS)."""

ALPHA_MAX = 0.99
"""alpha is clamped to this, so no single splat is fully opaque (3DGS)."""

ALPHA_MIN = 1.0 / 255.0
"""A (pixel, Gaussian) pair takes part only when its alpha reaches this (3DGS)."""

FRUSTUM_CLAMP = 1.3
"""t_x / t_z is clamped to this many half-fields of view inside the Jacobian J (3DGS)."""
