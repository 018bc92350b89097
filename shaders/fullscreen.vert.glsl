#version 330 core
// A triangle covering the viewport, from gl_VertexID alone (draw 3 vertices, no buffers).

out vec2 uv;  // (0, 0) at the viewport's bottom-left, (1, 1) at its top-right

void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);  // (0, 0), (2, 0), (0, 2)
    uv = p;
    gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}
