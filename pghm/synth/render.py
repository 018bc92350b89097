"""Offscreen ModernGL renderer of a textured, lit, posed body mesh (the synthetic images).

Camera model (the project's, as :mod:`pghm.splat.camera`): pinhole, OpenCV axes (x right,
y down, z forward), a world point X goes to t = R X + T (``world_to_camera`` = [R T; 0 1])
and to the pixel position (u, v) = (fx t_x / t_z + cx, fy t_y / t_z + cy); pixel (row i,
column j) has its centre at (j + 0.5, i + 0.5).

GL projection consistent with it: with near n and far f,

    clip = P t,   P = [[2 fx / W, 0,        2 cx / W - 1,       0           ],
                       [0,        2 fy / H, 2 cy / H - 1,       0           ],
                       [0,        0,        (f + n) / (f - n), -2 f n / (f - n)],
                       [0,        0,        1,                  0           ]]

so x_ndc = 2 u / W - 1 and y_ndc = 2 v / H - 1; the viewport maps these to window
coordinates (u, v) exactly, and GL samples pixel (j, r) at window (j + 0.5, r + 0.5).
There is no y flip: framebuffer row r (which ``glReadPixels`` returns first) is image row
i = r, so a read-back needs no flipping. The mirror makes outward-facing triangles wind
clockwise on screen, so ``front_face = "cw"``. Back faces are culled (halving
llvmpipe's triangle work): the body surface is closed, and cameras never look up inside a
skirt.

Anti-aliasing is MSAA (``samples`` per pixel) resolved by averaging. The colour target is
cleared to (1, 1, 1, 0) and every fragment writes alpha 1, so after the resolve

    rgb   = c k / S + (1 - k / S)     the image composited on white,
    alpha = k / S                     the pixel's coverage (k of S samples covered).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import moderngl
import numpy as np

import shaders

NEAR_PLANE = 0.05
"""Metres; closest depth drawn (cameras stand >= 1 m from the body)."""

FAR_PLANE = 50.0
"""Metres; farthest depth drawn."""

BUMP_DEPTH = 0.006
"""Metres of fold height at |h| = 1 used for the bump-mapped shading of wrinkles."""

FOLD_DARKENING = 0.45
"""Albedo lost at the bottom of a fold (h = -1): ambient occlusion of the valley."""

HEMI_GROUND = 0.55
"""Ambient fraction reaching a downward-facing normal (sky light from above)."""

WRINKLE_CHANNELS = 8
"""Fold patterns G_k carried by the two RGBA wrinkle textures."""

MASK_COVERAGE = 0.5
"""A pixel belongs to the foreground mask when at least this fraction of it is covered."""

_DEFINES: dict[str, int | float] = {
    "BUMP_DEPTH": BUMP_DEPTH,
    "FOLD_DARKENING": FOLD_DARKENING,
    "HEMI_GROUND": HEMI_GROUND,
}


def projection_matrix(K: np.ndarray, width: int, height: int) -> np.ndarray:  # noqa: N803
    """(4, 4) GL projection P of the module docstring for intrinsics K (3, 3)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    n, f = NEAR_PLANE, FAR_PLANE
    return np.array(
        [
            [2 * fx / width, 0.0, 2 * cx / width - 1, 0.0],
            [0.0, 2 * fy / height, 2 * cy / height - 1, 0.0],
            [0.0, 0.0, (f + n) / (f - n), -2 * f * n / (f - n)],
            [0.0, 0.0, 1.0, 0.0],
        ]
    )


def project_points(points: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray) -> np.ndarray:  # noqa: N803
    """(N, 2) pixel positions (u, v) of world points (N, 3): the camera model's reference."""
    cam = points @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    return np.stack([K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]], axis=1)


@dataclass(frozen=True)
class Lighting:
    """One directional light plus hemispherical ambient, fixed in the world.

    Attributes:
        direction: (3,) unit vector from the body towards the light.
        colour: (3,) light intensity per channel (linear).
        ambient: ambient intensity (linear).
        shininess: Blinn-Phong exponent.
    """

    direction: tuple[float, float, float]
    colour: tuple[float, float, float]
    ambient: float
    shininess: float


@dataclass(frozen=True)
class RenderedView:
    """One rendered image.

    Attributes:
        rgb: (H, W, 3) uint8, composited on white.
        coverage: (H, W) uint8, 255 x the covered fraction of each pixel.
    """

    rgb: np.ndarray
    coverage: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H, W) uint8 foreground mask, 0 or 255: coverage >= MASK_COVERAGE."""
        return np.where(self.coverage >= round(255 * MASK_COVERAGE), 255, 0).astype(np.uint8)


def render_vertices(faces: np.ndarray, uv_faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split mesh vertices along UV seams into GL vertices (one per (vertex, uv) pair).

    Args:
        faces: (F, 3) vertex indices.
        uv_faces: (F, 3) texture-coordinate indices.

    Returns:
        vertex: (R,) mesh vertex of each GL vertex.
        uv: (R,) texture coordinate of each GL vertex.
        triangles: (F, 3) GL vertex indices.
    """
    stride = int(uv_faces.max()) + 1
    pairs = faces.astype(np.int64) * stride + uv_faces
    unique, inverse = np.unique(pairs.reshape(-1), return_inverse=True)
    return unique // stride, unique % stride, inverse.reshape(-1, 3)


class MeshRenderer:
    """Draws one body mesh (fixed topology) into W x H images with MSAA.

    Set-up (programs, buffers, framebuffers) happens once in ``__init__``; per identity
    call :meth:`set_textures`, per pose :meth:`set_geometry`, per view :meth:`render`.
    Release with :meth:`release` or use as a context manager.

    Args:
        ctx: a current moderngl context (:func:`pghm.gl.headless_context`).
        faces: (F, 3) vertex indices of the mesh.
        uv_faces: (F, 3) texture-coordinate indices.
        uv_coords: (T, 2) texture coordinates, v up.
        width, height: image size W, H.
        samples: MSAA samples per pixel (clamped to the driver's maximum).
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        faces: np.ndarray,
        uv_faces: np.ndarray,
        uv_coords: np.ndarray,
        width: int,
        height: int,
        samples: int = 4,
    ) -> None:
        self.ctx = ctx
        self.width, self.height = int(width), int(height)
        self.samples = max(1, min(int(samples), ctx.max_samples))
        self._vertex, uv_index, triangles = render_vertices(np.asarray(faces), np.asarray(uv_faces))
        self.program = ctx.program(
            vertex_shader=shaders.source("synth_mesh.vert"),
            fragment_shader=shaders.source("synth_mesh.frag", _DEFINES),
        )
        uv = np.ascontiguousarray(np.asarray(uv_coords, dtype=np.float32)[uv_index])
        self._geometry = ctx.buffer(reserve=len(self._vertex) * 6 * 4, dynamic=True)
        self._uv = ctx.buffer(uv.tobytes())
        self._index = ctx.buffer(triangles.astype(np.int32).tobytes())
        self.vao = ctx.vertex_array(
            self.program,
            [(self._geometry, "3f 3f", "in_position", "in_normal"), (self._uv, "2f", "in_uv")],
            index_buffer=self._index,
            index_element_size=4,
        )
        size = (self.width, self.height)
        self._msaa = ctx.framebuffer(
            color_attachments=[ctx.renderbuffer(size, 4, samples=self.samples)],
            depth_attachment=ctx.depth_renderbuffer(size, samples=self.samples),
        )
        self._resolved = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 4)])
        self._textures: list[moderngl.Texture] = []

    def __enter__(self) -> MeshRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def release(self) -> None:
        """Free every GL object this renderer created."""
        for texture in self._textures:
            texture.release()
        self._textures = []
        for fbo in (self._msaa, self._resolved):
            for attachment in (*fbo.color_attachments, fbo.depth_attachment):
                if attachment is not None:
                    attachment.release()
            fbo.release()
        for obj in (self.vao, self._geometry, self._uv, self._index, self.program):
            obj.release()

    def set_textures(self, albedo: np.ndarray, wrinkles: np.ndarray) -> None:
        """Upload one identity's maps (row 0 = the top of the UV square, v = 1).

        Args:
            albedo: (L, L, 4) uint8, sRGB albedo and specular strength.
            wrinkles: (L, L, 8) float32 fold patterns G_k in [-1, 1].
        """
        for texture in self._textures:
            texture.release()
        self._textures = []
        # GL's texture row 0 is v = 0, the bottom of the UV square: flip the image rows.
        maps = [(np.flipud(albedo), "f1"), (np.flipud(wrinkles[..., :4]), "f4"), (np.flipud(wrinkles[..., 4:]), "f4")]
        for unit, (data, dtype) in enumerate(maps):
            texture = self.ctx.texture(data.shape[1::-1], 4, np.ascontiguousarray(data).tobytes(), dtype=dtype)
            texture.build_mipmaps()
            texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
            texture.repeat_x = texture.repeat_y = False
            texture.use(unit)
            self._textures.append(texture)
        self.program["albedo_map"].value = 0
        self.program["wrinkle_map0"].value = 1
        self.program["wrinkle_map1"].value = 2

    def set_geometry(self, positions: np.ndarray, normals: np.ndarray) -> None:
        """Upload one posed mesh: positions and unit normals (V, 3) of the mesh vertices."""
        data = np.concatenate([positions[self._vertex], normals[self._vertex]], axis=1)
        self._geometry.write(np.ascontiguousarray(data, dtype=np.float32).tobytes())

    def render(
        self,
        K: np.ndarray,  # noqa: N803
        world_to_camera: np.ndarray,
        lighting: Lighting,
        wrinkle_amplitudes: np.ndarray | None = None,
        mode: Literal["lit", "albedo"] = "lit",
    ) -> RenderedView:
        """Draw the current mesh from one camera.

        Args:
            K: (3, 3) intrinsics.
            world_to_camera: (4, 4) extrinsics, OpenCV axes.
            lighting: the light.
            wrinkle_amplitudes: (8,) a_k in [0, 1] (None: no folds).
            mode: "lit" (the dataset image) or "albedo" (the static texture, unlit).
        """
        K = np.asarray(K, dtype=np.float64)
        world_to_camera = np.asarray(world_to_camera, dtype=np.float64)
        clip_from_world = projection_matrix(K, self.width, self.height) @ world_to_camera
        amplitudes = np.zeros(WRINKLE_CHANNELS) if wrinkle_amplitudes is None else np.asarray(wrinkle_amplitudes)
        centre = -world_to_camera[:3, :3].T @ world_to_camera[:3, 3]
        program = self.program
        # GLSL mat4 uniforms are column-major: upload the transpose of the row-major matrix.
        program["clip_from_world"].write(clip_from_world.T.astype(np.float32).tobytes())
        program["camera_centre"].value = tuple(float(c) for c in centre)
        program["light_direction"].value = tuple(float(c) for c in lighting.direction)
        program["light_colour"].value = tuple(float(c) for c in lighting.colour)
        program["ambient"].value = float(lighting.ambient)
        program["shininess"].value = float(lighting.shininess)
        program["wrinkle_amplitude0"].value = tuple(float(a) for a in amplitudes[:4])
        program["wrinkle_amplitude1"].value = tuple(float(a) for a in amplitudes[4:])
        program["albedo_only"].value = 1 if mode == "albedo" else 0
        for unit, texture in enumerate(self._textures):
            texture.use(unit)
        self._msaa.use()
        self.ctx.viewport = (0, 0, self.width, self.height)
        self._msaa.clear(1.0, 1.0, 1.0, 0.0, depth=1.0)
        self.ctx.front_face = "cw"
        self.ctx.enable_only(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        self.vao.render(moderngl.TRIANGLES)
        self.ctx.copy_framebuffer(self._resolved, self._msaa)
        pixels = np.frombuffer(self._resolved.read(components=4), dtype=np.uint8)
        pixels = pixels.reshape(self.height, self.width, 4)
        return RenderedView(rgb=np.ascontiguousarray(pixels[..., :3]), coverage=np.ascontiguousarray(pixels[..., 3]))
