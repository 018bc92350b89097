"""GL drawing the viewer adds over the sprites: overlays (points, mesh lines).

:class:`OverlayRenderer` draws the Gaussian centres as points and the posed body mesh as
lines, projected exactly like the sprites (``shaders/viewer_overlay.vert.glsl``).

Programs and buffers are created once in ``__init__`` (buffers grown on demand) and freed
by ``release``.
"""

from __future__ import annotations

import moderngl
import numpy as np

from pghm.gl.resources import build_program

CENTRE_COLOUR = (0.1, 0.9, 0.3, 0.8)
"""RGBA of the Gaussian-centre points."""
MESH_COLOUR = (0.2, 0.6, 1.0, 0.35)
"""RGBA of the body mesh lines."""
POINT_SIZE = 2.0
"""Pixels per centre point."""
BYTES_PER_POSITION = 12
"""A float32 (x, y, z)."""


def _set_camera(program: moderngl.Program, camera) -> None:
    """The camera uniforms shared by the overlay shader and the sprite shader's conventions."""
    w2c = camera.world_to_camera.double().numpy()
    # GLSL matrices are column-major: write the transpose.
    program["world_to_camera"].write(w2c.T.astype(np.float32).tobytes())
    program["focal"] = (float(camera.fx), float(camera.fy))
    program["principal"] = (float(camera.cx), float(camera.cy))
    program["image_size"] = (float(camera.width), float(camera.height))


def _write(buffer: moderngl.Buffer, positions: np.ndarray) -> int:
    """Write positions (N, 3) as float32 into ``buffer`` (grown if too small); returns N."""
    data = np.ascontiguousarray(positions, dtype=np.float32)
    if data.nbytes > buffer.size:
        buffer.orphan(data.nbytes)
    buffer.write(data)
    return data.shape[0]


class OverlayRenderer:
    """Points and lines over the scene viewport, alpha-blended, no depth test."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self._program = build_program(ctx, "viewer_overlay.vert", "viewer_overlay.frag")
        self._points = ctx.buffer(reserve=BYTES_PER_POSITION)
        self._vertices = ctx.buffer(reserve=BYTES_PER_POSITION)
        self._edges = ctx.buffer(reserve=8)
        self._point_vao = ctx.vertex_array(self._program, [(self._points, "3f", "position")])
        self._mesh_vao = ctx.vertex_array(self._program, [(self._vertices, "3f", "position")], self._edges, 4)
        self._point_count = 0
        self._edge_count = 0

    def set_points(self, points: np.ndarray) -> None:
        """Gaussian centres (N, 3)."""
        self._point_count = _write(self._points, points)

    def set_mesh(self, vertices: np.ndarray, edges: np.ndarray | None = None) -> None:
        """Mesh vertices (V, 3); ``edges`` (E, 2) uint32 when the topology is new."""
        if edges is not None:
            data = np.ascontiguousarray(edges, dtype=np.uint32)
            if data.nbytes > self._edges.size:
                self._edges.orphan(data.nbytes)
            self._edges.write(data)
            self._edge_count = data.size
        _write(self._vertices, vertices)

    def draw(self, camera, viewport: tuple[int, int, int, int], centres: bool, mesh: bool) -> None:
        """Draw the chosen overlays into ``viewport`` of the bound framebuffer for ``camera`` (its W x H)."""
        if not (centres and self._point_count) and not (mesh and self._edge_count):
            return
        self.ctx.viewport = viewport
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        self.ctx.enable(moderngl.BLEND | moderngl.PROGRAM_POINT_SIZE)
        self.ctx.blend_equation = moderngl.FUNC_ADD
        self.ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        _set_camera(self._program, camera)
        self._program["point_size"] = POINT_SIZE
        if mesh and self._edge_count:
            self._program["color"] = MESH_COLOUR
            self._mesh_vao.render(moderngl.LINES, vertices=self._edge_count)
        if centres and self._point_count:
            self._program["color"] = CENTRE_COLOUR
            self._point_vao.render(moderngl.POINTS, vertices=self._point_count)
        self.ctx.disable(moderngl.BLEND | moderngl.PROGRAM_POINT_SIZE)

    def release(self) -> None:
        for resource in (self._point_vao, self._mesh_vao, self._points, self._vertices, self._edges, self._program):
            resource.release()
