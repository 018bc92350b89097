"""The differentiable CPU splatter: isotropic 3D Gaussians to an image, exactly as specified here.

This docstring is the specification; ``docs/splat.md`` repeats it with the design and the
measurements. It is 3DGS / EWA splatting (Kerbl et al. 2023, "3D Gaussian Splatting for
Real-Time Radiance Field Rendering"; Zwicker et al. 2002, "EWA Splatting") specialised to
isotropic Gaussians, to which the paper constrains every Gaussian (its "Preliminaries").

Inputs, one image per camera (B images, N Gaussians, H x W pixels):

    means mu (N, 3) world positions     scales s (N,) world standard deviations
    colors c (N, 3)                     opacities o (N,)
    camera: fx, fy, cx, cy, W, H and world_to_camera [R T; 0 1], OpenCV axes
            (x right, y down, z forward)

Every input must be finite: a NaN or infinite value is a PghmError naming the argument,
never a silently dropped Gaussian or a NaN image. Any finite value is accepted (negative
opacities and colours outside [0, 1] included: the formulas below say what they do).

1. Pixel (row i, column j) has its centre at (j + 0.5, i + 0.5).
2. Camera space: t = R mu + T. A Gaussian with t_z <= NEAR_PLANE (0.01) is dropped.
3. Screen mean: u = fx t_x / t_z + cx, v = fy t_y / t_z + cy.
4. Screen covariance (EWA): cov2d = s^2 J J^T + COV_DILATION I (0.3 px^2), with

       J = [[fx / t_z, 0, -fx x' / t_z^2], [0, fy / t_z, -fy y' / t_z^2]],
       x' = clamp(t_x / t_z, -L_x, L_x) t_z,  L_x = FRUSTUM_CLAMP W / (2 fx)  (1.3, same for y, H, fy).

   The clamp enters J only, never the mean. conic Q = inverse(cov2d).
5. Opacity of Gaussian n at pixel p, with d = pixel centre - (u, v):

       alpha = min(ALPHA_MAX, o exp(-d^T Q d / 2)),  ALPHA_MAX = 0.99,

   and the pair (p, n) takes part only when alpha >= ALPHA_MIN = 1/255. Nothing else truncates:
   a Gaussian's footprint is exactly {d : d^T Q d <= 2 ln(255 o)}, inside the circle of radius
   sqrt(2 ln(255 o) lambda_max(cov2d)), not a fixed 3 sigma.
6. Front-to-back compositing in order of t_z (stable sort: ties keep index order), with
   T_i = prod_{j<i} (1 - alpha_j) over the pixel's pairs and no early termination:

       rgb   = sum_i c_i alpha_i T_i + T_N background
       alpha = 1 - T_N                     (accumulated opacity)
       depth = sum_i t_z,i alpha_i T_i     (alpha-weighted view depth, not normalised)

   A global depth sort gives every pixel the same order as per-tile sorting, so a
   sorted-sprite GL renderer can reproduce this image exactly.
7. Gradients are those of the included terms: zero through min(ALPHA_MAX, .) where it clamps
   (as 3DGS); the ALPHA_MIN cut-off makes alpha discontinuous at the footprint's rim.

Gradients flow to means, scales, colors, opacities and, when it requires grad, to the
camera's world_to_camera (pose refinement). CUDA tensors render through gsplat
(:mod:`pghm.splat.gsplat_backend`, the ``gpu`` extra), which follows this spec in float32
with the differences listed there. :class:`SplatSettings` switches on measured
approximations (all off by default).

Public surface::

    from pghm.splat import Camera, render
    out = render(means, scales, colors, opacities, Camera(...), background=(1.0, 1.0, 1.0))
    out.rgb (H, W, 3), out.alpha (H, W), out.depth (H, W)     # (B, ...) for batched inputs
"""

from pghm.splat._render import RenderOutput, render
from pghm.splat._settings import SplatSettings
from pghm.splat.camera import Camera

__all__ = ["Camera", "RenderOutput", "SplatSettings", "render"]
