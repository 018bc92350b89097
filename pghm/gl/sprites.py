"""Isotropic 3D Gaussians drawn as GL sprites (points or instanced quads), equal to the CPU splatter's image.

The GL twin of ``pghm.splat.render`` (tests hold the two to max abs error 2e-3). Per
Gaussian, the vertex shader (``shaders/gaussian_sprite.vert.glsl``) projects the centre,
builds cov2d = s^2 J J^T + 0.3 I with the frustum clamp in J, its inverse (the conic) and
a quad circumscribing the footprint {alpha >= 1/255}; the fragment shader evaluates
alpha = min(0.99, o exp(-0.5 d^T conic d)) at the pixel centre and discards it below 1/255.

Compositing. The splatter sums, over Gaussians sorted front to back,

    C = sum_i c_i alpha_i T_i + T_N background,   T_i = prod_{j<i} (1 - alpha_j).

The fragment outputs premultiplied (c alpha, alpha) and the blend (ONE_MINUS_DST_ALPHA,
ONE) adds src (1 - dst.a) to dst. Starting from dst = (0, 0, 0, 0), by induction
1 - dst.a = prod_{j<i} (1 - alpha_j) = T_i before Gaussian i, because
1 - (a + (1 - a) alpha) = (1 - a)(1 - alpha); hence dst.rgb = sum_i c_i alpha_i T_i and
dst.a = 1 - T_N, and C = dst.rgb + (1 - dst.a) background, composited last. The target
is RGBA32F, so this holds up to float32 rounding. The optional depth attachment blends
(z alpha, 0, 0, alpha) the same way: sum_i z_i alpha_i T_i.

Only the screen box holding every quad (:mod:`pghm.gl.footprint`) is cleared and
composited; outside it the image is exactly the background.

Primitive. A sprite is one GL point (a square of side 2 e sqrt(max(a, c)), e = the
footprint's radius in standard deviations) when every square fits the driver's largest point
size, else one instanced quad (a parallelogram circumscribing the footprint ellipse). Both
cover the footprint, the fragment shader applies the exact cut-off, so the image is the same;
llvmpipe draws points 28-34% faster (docs/viewer.md). GL clips points by their centre, hence
the viewport guard band (``shaders/gaussian_sprite.vert.glsl``).

Orientation. Pixel p is placed at NDC = 2 (p + guard) / ((W, H) + 2 guard) - 1 with no flip
(guard = 0 for quads), so GL window
row r (bottom row 0) holds image row r and gl_FragCoord.xy = (j + 0.5, i + 0.5) is the
spec's pixel centre. Read-back returns GL row 0 first, i.e. image row 0 (the top) first;
only presentation in a window flips (``draw(..., flip_y=True)``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Literal, Protocol

import moderngl
import numpy as np

from pghm.errors import PghmError
from pghm.gl.cull import camera_centre, facing
from pghm.gl.footprint import Box, Extent, grow, sprite_extent
from pghm.gl.resources import (
    MAX_GAUSSIANS,
    TEXTURE_WIDTH,
    as_array,
    build_program,
    float_texture,
    texture_rows,
)
from pghm.gl.sort import BitonicSorter, depth_order, view_depths


class CameraLike(Protocol):
    """A pinhole camera as ``pghm.splat.Camera`` (duck-typed on these attributes).

    OpenCV axes: x right, y down, z forward. ``world_to_camera`` is (4, 4), numpy or torch.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    world_to_camera: object


@dataclass(frozen=True)
class _Pinhole:
    """A validated camera: intrinsics in pixels and world_to_camera (4, 4) in float64.

    The depth order is computed from the float64 matrix, as the CPU splatter does (float32
    depths tie or swap Gaussians less than ~1e-7 t_z apart); the shader gets float32.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    world_to_camera: np.ndarray

    @staticmethod
    def of(camera: CameraLike) -> _Pinhole:
        w2c = as_array("camera.world_to_camera", camera.world_to_camera, (4, 4), np.float64)
        width, height = int(camera.width), int(camera.height)
        if width <= 0 or height <= 0:
            raise PghmError(f"camera size must be positive, got {width} x {height}")
        return _Pinhole(float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy), width, height, w2c)


@dataclass
class FrameTimings:
    """Wall-clock milliseconds of the stages of the last frame, for a HUD.

    Attributes:
        sort_ms: CPU work per camera: the sprites' screen box and, when the camera's
            depth axis or the Gaussians changed, the depth order (``sorted``).
        upload_ms: Gaussian textures (only after ``set_gaussians``) and the draw order.
        draw_ms: sprite pass (and, in ``draw``, the composite), waited for with
            ``ctx.finish()``.
        readback_ms: ``render`` only: composite pass and copy of the float image to numpy.
        sorted: whether this frame sorted.
        primitive: "points" or "quads", what the sprite pass drew ("" when nothing was drawn).
        drawn: sprites the pass was given (all Gaussians, or those kept by back-face culling).
    """

    sort_ms: float = 0.0
    upload_ms: float = 0.0
    draw_ms: float = 0.0
    readback_ms: float = 0.0
    sorted: bool = False
    primitive: str = ""
    drawn: int = 0

    @property
    def total_ms(self) -> float:
        """The sum of the stages."""
        return self.sort_ms + self.upload_ms + self.draw_ms + self.readback_ms


@dataclass(frozen=True)
class SpriteImage:
    """A rendered image, row 0 at the top (the splatter's orientation).

    Attributes:
        rgb: (H, W, 3) float32, C = sum_i c_i alpha_i T_i + T_N background.
        alpha: (H, W) float32 accumulated alpha 1 - T_N.
        depth: (H, W) float32 alpha-weighted view depth sum_i z_i alpha_i T_i, or None
            when not requested.
    """

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray | None


@dataclass(frozen=True)
class _Drawn:
    """The last draw(): the sprites' box in its W x H accumulation, the viewport size it was
    composited to, and whether rows were flipped."""

    box: Box | None
    size: tuple[int, int]
    viewport_size: tuple[int, int]
    flip_y: bool


@dataclass(frozen=True)
class _SpritePrograms:
    """The sprite programs of one projection precision: quads, and points unless quads are forced."""

    quads: moderngl.Program
    quads_vao: moderngl.VertexArray
    points: moderngl.Program | None
    points_vao: moderngl.VertexArray | None

    @staticmethod
    def build(ctx: moderngl.Context, precision: str, primitive: str) -> _SpritePrograms:
        quads = build_program(ctx, "gaussian_sprite.vert", "gaussian_sprite.frag", precision)
        points = (
            build_program(ctx, "gaussian_sprite.vert", "gaussian_sprite.frag", precision, {"PGHM_POINTS": 1})
            if primitive == "auto"
            else None
        )
        for program in (quads, points):
            if program is not None:
                program["mean_scale"] = 0
                program["color_opacity"] = 1
                program["draw_order"] = 2
        # Both programs make their vertices from gl_VertexID / gl_InstanceID: no buffers.
        return _SpritePrograms(
            quads, ctx.vertex_array(quads, []), points, ctx.vertex_array(points, []) if points is not None else None
        )

    def release(self) -> None:
        for resource in (self.quads_vao, self.points_vao, self.quads, self.points):
            if resource is not None:
                resource.release()


class SpriteRenderer:
    """Draws N isotropic Gaussians into a float target with OpenGL 3.3.

    Set-up (programs, vertex arrays) happens here, per-Gaussian textures in
    :meth:`set_gaussians` (reallocated only when N exceeds the capacity), the frame in
    :meth:`render` (offscreen, read back to numpy) or :meth:`draw` (into the current
    framebuffer, for the viewer); :meth:`release` frees every GL object created.

    Args:
        ctx: an OpenGL >= 3.3 context, e.g. :func:`pghm.gl.headless_context` or the
            viewer's window context. Calls must run with it current.
        sort: "cpu" (default, fastest on llvmpipe) or "gpu" (bitonic network in fragment
            passes; see :mod:`pghm.gl.sort`).
        precision: of the per-Gaussian projection. "double" (OpenGL 4.0 or
            GL_ARB_gpu_shader_fp64: the sprite shaders compiled with ``real`` = ``double``,
            see :mod:`shaders`) computes the screen mean and conic in float64 like the CPU
            splatter, which removes the rare cut-off flips of "float" (the OpenGL 3.3
            path, ``real`` = ``float``); "auto" (default) takes "double" when the context
            offers it. docs/viewer.md has the measurements.
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        sort: Literal["cpu", "gpu"] = "cpu",
        precision: Literal["auto", "float", "double"] = "auto",
        primitive: Literal["auto", "quads"] = "auto",
    ) -> None:
        if sort not in ("cpu", "gpu"):
            raise PghmError(f"sort must be 'cpu' or 'gpu', got {sort!r}")
        if precision not in ("auto", "float", "double"):
            raise PghmError(f"precision must be 'auto', 'float' or 'double', got {precision!r}")
        if primitive not in ("auto", "quads"):
            raise PghmError(f"primitive must be 'auto' or 'quads', got {primitive!r}")
        self.ctx = ctx
        self.timings = FrameTimings()
        if precision == "auto":
            precision = "double" if supports_fp64(ctx) else "float"
        _require_precision(ctx, precision)
        self.precision = precision
        """"float" or "double": the projection the sprite program uses."""
        self._primitive = primitive
        self._passes: dict[str, _SpritePrograms] = {precision: _SpritePrograms.build(ctx, precision, primitive)}
        self._largest_point = float(ctx.info["GL_POINT_SIZE_RANGE"][1])
        self._largest_viewport = tuple(int(v) for v in ctx.info["GL_MAX_VIEWPORT_DIMS"])
        self._composite = build_program(ctx, "fullscreen.vert", "composite.frag")
        self._composite["accum"] = 0
        self._composite_vao = ctx.vertex_array(self._composite, [])
        self._sorter = BitonicSorter(ctx) if sort == "gpu" else None

        self._count = 0
        self._rows = 0  # texture rows allocated: capacity = rows * TEXTURE_WIDTH
        self._mean_scale: moderngl.Texture | None = None
        self._color_opacity: moderngl.Texture | None = None
        self._cpu_order: moderngl.Texture | None = None
        self._mean_scale_staging = np.zeros((0, 4), np.float32)  # (capacity, 4): mu, s
        self._color_opacity_staging = np.zeros((0, 4), np.float32)  # (capacity, 4): c, o
        self._order_staging = np.zeros(0, np.float32)
        self._normals: np.ndarray | None = None  # (N, 3) for back-face culling, CPU only
        self._order_count = 0  # Gaussians in the draw order (fewer than N when culled)
        self._dirty = False
        self._version = 0  # bumped by set_gaussians; part of the sort cache key
        self._order: moderngl.Texture | None = None
        self._order_key: tuple[int, bytes] | None = None
        self._extent: Extent | None = None
        self._extent_key: tuple | None = None
        self._drawn: _Drawn | None = None  # what the accumulation holds, for present()

        self._size = (0, 0)
        self._accum: moderngl.Texture | None = None
        self._accum_depth: moderngl.Texture | None = None
        self._fbo: moderngl.Framebuffer | None = None
        self._fbo_depth: moderngl.Framebuffer | None = None
        self._image: moderngl.Texture | None = None  # render(): the composited image
        self._image_fbo: moderngl.Framebuffer | None = None

    @property
    def count(self) -> int:
        """N, the number of Gaussians last set."""
        return self._count

    def set_gaussians(
        self, means: object, scales: object, colors: object, opacities: object, normals: object | None = None
    ) -> None:
        """Replace the Gaussians; the textures are written at the next frame.

        Args:
            means: (N, 3) world positions.
            scales: (N,) standard deviations (world units).
            colors: (N, 3) RGB.
            opacities: (N,) in [0, 1].
            normals: (N, 3) unit surface normals, or None; only back-face culling
                (``draw(cull_degrees=...)``) reads them.
            All float32-convertible numpy arrays or torch tensors (detached, copied).
        """
        means = as_array("means", means, (-1, 3))
        count = means.shape[0]
        scales = as_array("scales", scales, (count,))
        colors = as_array("colors", colors, (count, 3))
        opacities = as_array("opacities", opacities, (count,))
        normals = as_array("normals", normals, (count, 3)).copy() if normals is not None else None
        if count > MAX_GAUSSIANS:
            raise PghmError(f"at most {MAX_GAUSSIANS} Gaussians are supported, got {count}")
        # Colours alone (e.g. view-dependent colour for a new view) keep the depth order, its
        # cull and the sprites' extent: they depend only on the means, scales, opacities and normals.
        same_geometry = (
            count == self._count
            and np.array_equal(self._mean_scale_staging[:count, :3], means)
            and np.array_equal(self._mean_scale_staging[:count, 3], scales)
            and np.array_equal(self._color_opacity_staging[:count, 3], opacities)
            and (normals is None) == (self._normals is None)
            and (normals is None or np.array_equal(self._normals, normals))
        )
        self._normals = normals
        self._reserve(texture_rows(count))
        self._mean_scale_staging[:count, :3] = means
        self._mean_scale_staging[:count, 3] = scales
        self._color_opacity_staging[:count, :3] = colors
        self._color_opacity_staging[:count, 3] = opacities
        self._count = count
        self._dirty = True
        if not same_geometry:
            self._version += 1

    def render(
        self, camera: CameraLike, background: tuple[float, float, float] = (1.0, 1.0, 1.0), depth: bool = False
    ) -> SpriteImage:
        """The image of the Gaussians seen by ``camera``, read back as float32 (H, W).

        ``background`` is composited under the sprites in float32 on the GPU, exactly
        C + (1 - A) background. ``depth=True`` adds the alpha-weighted depth. ``rgb`` and
        ``alpha`` are views into one (H, W, 4) array.
        """
        cam = _Pinhole.of(camera)
        size = (cam.width, cam.height)
        timings, box = self._accumulate(cam, depth, clear_margin=0, precision=self.precision, order_cam=cam)
        image_fbo = self._image_target(size)
        start = time.perf_counter()
        image = np.empty((cam.height, cam.width, 4), np.float32)
        image[..., :3] = background  # outside the box no sprite reaches: background, alpha 0
        image[..., 3] = 0.0
        depth_image = np.zeros((cam.height, cam.width), np.float32) if depth else None
        if box is not None:
            image_fbo.use()
            self._composite_into(box, (0, 0, *size), background, flip_y=False, opaque=False)
            x, y, w, h = box
            region = image_fbo.read(viewport=box, components=4, dtype="f4")
            image[y : y + h, x : x + w] = np.frombuffer(region, np.float32).reshape(h, w, 4)
            if depth:
                region = self._fbo_depth.read(viewport=box, components=4, attachment=1, dtype="f4")
                depth_image[y : y + h, x : x + w] = np.frombuffer(region, np.float32).reshape(h, w, 4)[..., 0]
        timings.readback_ms = _ms_since(start)
        self.timings = timings
        return SpriteImage(rgb=image[..., :3], alpha=image[..., 3], depth=depth_image)

    def draw(
        self,
        camera: CameraLike,
        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
        target: moderngl.Framebuffer | None = None,
        viewport: tuple[int, int, int, int] | None = None,
        flip_y: bool = True,
        precision: Literal["float", "double"] | None = None,
        order_camera: CameraLike | None = None,
        cleared: bool = False,
        cull_degrees: float | None = None,
    ) -> FrameTimings:
        """Draw the Gaussians over ``background`` into ``target``, for presentation.

        The sprites are accumulated at the camera's W x H, then composited opaque into
        ``viewport`` (x, y, width, height; default: the whole target) of ``target``
        (default: the framebuffer bound on entry, e.g. the window's), stretched
        bilinearly if the sizes differ: rendering at a fraction of the window size is
        how the viewer trades resolution for frame rate. ``flip_y`` shows image row 0 at
        the top of a window. Leaves ``target`` bound, BLEND and the scissor disabled.

        Two more trades for frames of a moving camera (defaults: the exact image):
        ``precision`` "float" projects in float32 even on a double-precision renderer
        (cheaper per Gaussian; rare cut-off flips, see the class), and ``order_camera``
        composites in the depth order of another camera, e.g. the view of a few degrees
        ago, whose order is cached (isotropic sprites: only overlapping ones swap).
        ``cull_degrees`` d (needs ``normals``): back-face culling, made with the depth order and
        cached with it: only the Gaussians facing the order camera's centre with a margin of d
        degrees past the silhouette (:func:`pghm.gl.cull.facing`) enter the order and the pass.
        ``cleared``: ``viewport`` already holds ``background`` (a window cleared whole, which
        llvmpipe does several times faster than the scissored clear of a viewport).
        """
        target = target if target is not None else self.ctx.fbo
        cam = _Pinhole.of(camera)
        order_cam = _Pinhole.of(order_camera) if order_camera is not None else cam
        viewport = viewport if viewport is not None else (0, 0, *target.size)
        scale = (viewport[2] / cam.width, viewport[3] / cam.height)
        # A window pixel inside the composite box samples within 0.5 / scale + 1 texels of
        # the sprite box: clear that far so bilinear taps never read a stale texel.
        margin = 2 + math.ceil(0.5 / min(scale))
        if cull_degrees is not None and self._normals is None:
            raise PghmError("back-face culling needs normals: pass them to set_gaussians")
        if cull_degrees is not None and self._sorter is not None:
            raise PghmError("back-face culling needs sort='cpu'")
        timings, box = self._accumulate(
            cam,
            depth=False,
            clear_margin=margin,
            precision=precision or self.precision,
            order_cam=order_cam,
            cull_degrees=cull_degrees,
        )
        self._drawn = _Drawn(box, (cam.width, cam.height), (viewport[2], viewport[3]), flip_y)
        start = time.perf_counter()
        self.present(background, target, viewport, cleared)
        self.ctx.finish()
        timings.draw_ms += _ms_since(start)
        self.timings = timings
        return timings

    def present(
        self,
        background: tuple[float, float, float],
        target: moderngl.Framebuffer | None = None,
        viewport: tuple[int, int, int, int] | None = None,
        cleared: bool = False,
    ) -> None:
        """Composite the last :meth:`draw`'s sprites again, into ``viewport`` of ``target``.

        Without new sprites this is all a frame needs (a window redrawn while the scene is
        unchanged): the clear and the composite of the sprites' box, not the sprite pass.
        ``viewport`` must have the last draw's size (its clear margin was made for that
        stretch); ``background`` and the position may differ. ``cleared``: as in :meth:`draw`.
        """
        drawn = self._drawn
        if drawn is None:
            raise PghmError("present() shows the last draw(); nothing was drawn since the last render()")
        target = target if target is not None else self.ctx.fbo
        viewport = viewport if viewport is not None else (0, 0, *target.size)
        if (viewport[2], viewport[3]) != drawn.viewport_size:
            raise PghmError(f"present() needs the last draw's viewport size {drawn.viewport_size}, got {viewport[2:]}")
        target.use()
        if not cleared:
            target.clear(*background, 1.0, viewport=viewport)
        if drawn.box is not None:
            screen_box = _map_box(drawn.box, drawn.size, viewport, drawn.flip_y)
            self._composite_into(screen_box, viewport, background, flip_y=drawn.flip_y, opaque=True)

    def release(self) -> None:
        """Free every GL object this renderer created (the context stays the caller's)."""
        self._release_targets()
        self._release_gaussian_textures()
        if self._sorter is not None:
            self._sorter.release()
        for programs in self._passes.values():
            programs.release()
        self._composite_vao.release()
        self._composite.release()

    def __enter__(self) -> SpriteRenderer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()

    # ----------------------------------------------------------------- per frame

    def _accumulate(
        self,
        cam: _Pinhole,
        depth: bool,
        clear_margin: int,
        precision: str,
        order_cam: _Pinhole,
        cull_degrees: float | None = None,
    ) -> tuple[FrameTimings, Box | None]:
        """Upload and sort if needed, then blend the sprites into the float target.

        The sprites are projected in ``precision`` and composited in the depth order of
        ``order_cam`` (``cam`` for the exact image), only those facing it when
        ``cull_degrees`` is given. Returns the stage timings and the box
        holding every sprite (None: nothing drawn); only the box grown by ``clear_margin``
        pixels is cleared.
        """
        timings = FrameTimings()
        size = (cam.width, cam.height)
        fbo = self._accumulation_target(size, depth)
        self._drawn = None  # the accumulation is about to change

        start = time.perf_counter()
        if self._dirty:
            rows = texture_rows(self._count)
            viewport, texels = (0, 0, TEXTURE_WIDTH, rows), rows * TEXTURE_WIDTH
            self._mean_scale.write(self._mean_scale_staging[:texels], viewport=viewport)
            self._color_opacity.write(self._color_opacity_staging[:texels], viewport=viewport)
            self._dirty = False
        timings.upload_ms = _ms_since(start)

        start = time.perf_counter()
        extent = self._bounds(cam)
        box = extent.box if extent is not None else None
        timings.sort_ms = _ms_since(start)
        # The order depends only on the depth axis: the third row of world_to_camera; the cull
        # on the camera's centre too.
        order_key = (self._version, order_cam.world_to_camera[2].tobytes(), cull_degrees)
        if cull_degrees is not None:
            order_key += (camera_centre(order_cam.world_to_camera).tobytes(),)
        if box is not None and order_key != self._order_key:
            self._sort(order_cam, timings, cull_degrees)
            self._order_key = order_key

        start = time.perf_counter()
        if box is not None:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0, viewport=grow(box, clear_margin, size))
            primitive, program, vao, guard = self._sprite_pass(extent, size, precision)
            self.ctx.viewport = (-guard, -guard, cam.width + 2 * guard, cam.height + 2 * guard)
            self.ctx.scissor = box
            self.ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            self.ctx.enable(moderngl.BLEND | moderngl.PROGRAM_POINT_SIZE)
            self.ctx.blend_equation = moderngl.FUNC_ADD
            self.ctx.blend_func = moderngl.ONE_MINUS_DST_ALPHA, moderngl.ONE  # front-to-back "under"
            self._mean_scale.use(0)
            self._color_opacity.use(1)
            self._order.use(2)
            # GLSL matrices are column-major: write the transpose.
            uniform_dtype = np.float64 if precision == "double" else np.float32
            program["world_to_camera"].write(cam.world_to_camera.T.astype(uniform_dtype).tobytes())
            program["focal"].write(np.array([cam.fx, cam.fy], uniform_dtype).tobytes())
            program["principal"].write(np.array([cam.cx, cam.cy], uniform_dtype).tobytes())
            program["image_size"] = (float(cam.width), float(cam.height))
            program["guard"] = float(guard)
            if primitive == "points":
                vao.render(moderngl.POINTS, vertices=self._order_count)
            else:
                vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=self._order_count)
            timings.primitive = primitive
            timings.drawn = self._order_count
            self.ctx.disable(moderngl.BLEND | moderngl.PROGRAM_POINT_SIZE)
            self.ctx.scissor = None
            self.ctx.viewport = (0, 0, *size)
            self.ctx.finish()
        timings.draw_ms = _ms_since(start)
        return timings, box

    def _sprite_pass(
        self, extent: Extent, size: tuple[int, int], precision: str
    ) -> tuple[str, moderngl.Program, moderngl.VertexArray, int]:
        """Primitive ("points" or "quads"), program, vertex array and viewport guard (pixels)
        of this frame's sprite pass in ``precision`` (its programs built on first use).

        Points when the renderer may use them, every square fits the driver's largest point
        size and the guarded viewport fits its largest viewport; quads otherwise (no guard).
        """
        if precision not in self._passes:
            _require_precision(self.ctx, precision)
            self._passes[precision] = _SpritePrograms.build(self.ctx, precision, self._primitive)
        programs = self._passes[precision]
        if programs.points is not None:
            guard = math.ceil(extent.largest_point_half) + 1
            fits_point = 2.0 * extent.largest_point_half <= self._largest_point
            fits_viewport = all(n + 2 * guard <= limit for n, limit in zip(size, self._largest_viewport))
            if fits_point and fits_viewport:
                return "points", programs.points, programs.points_vao, guard
        return "quads", programs.quads, programs.quads_vao, 0

    def _bounds(self, cam: _Pinhole) -> Extent | None:
        """The sprites' extent, recomputed when the camera or the Gaussians change."""
        key = (self._version, cam.world_to_camera.tobytes(), cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        if key != self._extent_key:
            count = self._count
            self._extent = sprite_extent(
                self._mean_scale_staging[:count, :3],
                self._mean_scale_staging[:count, 3],
                self._color_opacity_staging[:count, 3],
                cam.world_to_camera,
                (cam.fx, cam.fy),
                (cam.cx, cam.cy),
                (cam.width, cam.height),
            )
            self._extent_key = key
        return self._extent

    def _composite_into(
        self, box: Box, viewport: tuple[int, int, int, int], background: tuple, flip_y: bool, opaque: bool
    ) -> None:
        """Composite the accumulation over ``background`` into ``viewport`` of the bound framebuffer, within ``box``."""
        self.ctx.viewport = viewport
        self.ctx.scissor = box
        stretched = (viewport[2], viewport[3]) != self._size
        self._accum.filter = (moderngl.LINEAR, moderngl.LINEAR) if stretched else (moderngl.NEAREST, moderngl.NEAREST)
        self._accum.use(0)
        self._composite["background"] = tuple(float(b) for b in background)
        self._composite["flip_y"] = flip_y
        self._composite["opaque"] = opaque
        self._composite_vao.render(moderngl.TRIANGLES, vertices=3)
        self.ctx.scissor = None

    def _sort(self, cam: _Pinhole, timings: FrameTimings, cull_degrees: float | None = None) -> None:
        """Recompute the front-to-back order into ``self._order`` (of the Gaussians facing
        ``cam`` when ``cull_degrees`` is given); adds to sort/upload times."""
        start = time.perf_counter()
        if self._sorter is not None:
            self._order = self._sorter.sort(self._mean_scale, self._count, cam.world_to_camera)
            self._order_count = self._count
            self.ctx.finish()  # so that sort_ms measures the GPU work, not its submission
            timings.sort_ms += _ms_since(start)
        else:
            means = self._mean_scale_staging[: self._count, :3]
            if cull_degrees is None:
                order = depth_order(view_depths(means, cam.world_to_camera))
            else:
                # The kept indices ascend, so ties stay in index order within the kept ones.
                kept = np.flatnonzero(facing(means, self._normals, camera_centre(cam.world_to_camera), cull_degrees))
                order = kept[depth_order(view_depths(means[kept], cam.world_to_camera))]
            self._order_count = order.size
            timings.sort_ms += _ms_since(start)
            start = time.perf_counter()
            rows = texture_rows(self._order_count)
            self._order_staging[: self._order_count] = order  # exact: indices < 2^24
            self._cpu_order.write(self._order_staging[: rows * TEXTURE_WIDTH], viewport=(0, 0, TEXTURE_WIDTH, rows))
            self._order = self._cpu_order
            timings.upload_ms += _ms_since(start)
        timings.sorted = True

    # ------------------------------------------------------------------ resources

    def _reserve(self, rows: int) -> None:
        """Textures for at least ``rows`` * TEXTURE_WIDTH Gaussians (grown, never shrunk)."""
        if rows <= self._rows:
            return
        self._release_gaussian_textures()
        self._mean_scale = float_texture(self.ctx, rows, 4)
        self._color_opacity = float_texture(self.ctx, rows, 4)
        if self._sorter is None:
            self._cpu_order = float_texture(self.ctx, rows, 1)
            self._order_staging = np.zeros(rows * TEXTURE_WIDTH, np.float32)
        self._mean_scale_staging = np.zeros((rows * TEXTURE_WIDTH, 4), np.float32)
        self._color_opacity_staging = np.zeros((rows * TEXTURE_WIDTH, 4), np.float32)
        self._rows = rows
        self._order_key = None  # the old order texture is gone

    def _accumulation_target(self, size: tuple[int, int], depth: bool) -> moderngl.Framebuffer:
        """The RGBA32F accumulation framebuffer of ``size`` = (W, H), with the depth attachment if asked."""
        if size != self._size:
            self._release_targets()
            self._accum = self.ctx.texture(size, 4, dtype="f4")
            self._fbo = self.ctx.framebuffer(color_attachments=[self._accum])
            self._size = size
        if not depth:
            return self._fbo
        if self._fbo_depth is None:
            self._accum_depth = self.ctx.texture(size, 4, dtype="f4")
            self._fbo_depth = self.ctx.framebuffer(color_attachments=[self._accum, self._accum_depth])
        return self._fbo_depth

    def _image_target(self, size: tuple[int, int]) -> moderngl.Framebuffer:
        """The RGBA32F framebuffer ``render`` composites into before reading back."""
        if self._image_fbo is None or self._image_fbo.size != size:
            if self._image_fbo is not None:
                self._image_fbo.release()
                self._image.release()
            self._image = self.ctx.texture(size, 4, dtype="f4")
            self._image_fbo = self.ctx.framebuffer(color_attachments=[self._image])
        return self._image_fbo

    def _release_targets(self) -> None:
        for resource in (self._fbo_depth, self._fbo, self._accum_depth, self._accum, self._image_fbo, self._image):
            if resource is not None:
                resource.release()
        self._fbo_depth = self._fbo = self._accum_depth = self._accum = self._image_fbo = self._image = None
        self._size = (0, 0)
        self._drawn = None

    def _release_gaussian_textures(self) -> None:
        for resource in (self._mean_scale, self._color_opacity, self._cpu_order):
            if resource is not None:
                resource.release()
        self._mean_scale = self._color_opacity = self._cpu_order = None
        self._rows = 0


FP64_VERSION = 400
"""OpenGL 4.0 made double-precision shader arithmetic core (moderngl version code)."""


def supports_fp64(ctx: moderngl.Context) -> bool:
    """Whether ``ctx`` runs double-precision shaders (OpenGL >= 4.0 or GL_ARB_gpu_shader_fp64)."""
    return ctx.version_code >= FP64_VERSION or "GL_ARB_gpu_shader_fp64" in ctx.extensions


def _require_precision(ctx: moderngl.Context, precision: str) -> None:
    """Raise PghmError unless ``ctx`` runs sprite programs in ``precision`` ("float" or "double")."""
    if precision not in ("float", "double"):
        raise PghmError(f"precision must be 'float' or 'double', got {precision!r}")
    if precision == "double" and not supports_fp64(ctx):
        version = ctx.info["GL_VERSION"]
        raise PghmError(f"precision='double' needs OpenGL 4.0 or GL_ARB_gpu_shader_fp64; this context has {version}")


def _map_box(box: Box, size: tuple[int, int], viewport: tuple[int, int, int, int], flip_y: bool) -> Box:
    """``box`` of an image of ``size`` = (W, H) as window pixels of ``viewport``, rounded outwards."""
    x, y, w, h = box
    if flip_y:
        y = size[1] - (y + h)
    sx, sy = viewport[2] / size[0], viewport[3] / size[1]
    x0, y0 = math.floor(x * sx), math.floor(y * sy)
    x1, y1 = math.ceil((x + w) * sx), math.ceil((y + h) * sy)
    return viewport[0] + x0, viewport[1] + y0, x1 - x0, y1 - y0


def _ms_since(start: float) -> float:
    return (time.perf_counter() - start) * 1e3
