#version 330 core
// Synthetic-data mesh renderer (pghm.synth.render): one LBS-posed, clothed body mesh.
// Positions and normals arrive already posed, in world space (metres, y up); the CPU
// builds clip_from_world = P world_to_camera, P the projection made from the OpenCV
// intrinsics K with no y flip, so that GL's framebuffer row r holds image row r (see
// pghm/synth/render.py).

in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;

uniform mat4 clip_from_world;

out vec3 v_world;
out vec3 v_normal;
// centroid: with MSAA an edge pixel's texture lookup stays inside the triangle (and the
// UV island), instead of extrapolating past it into another island's texels.
centroid out vec2 v_uv;

void main() {
    v_world = in_position;
    v_normal = in_normal;
    v_uv = in_uv;
    gl_Position = clip_from_world * vec4(in_position, 1.0);
}
