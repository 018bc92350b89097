#version 330 core
// Viewer overlays (Gaussian centres as points, the body mesh as lines), projected with the
// same pinhole camera as the sprites: t = R p + T, (u, v) = (fx t.x / t.z + cx, fy t.y / t.z + cy).
// Clip space keeps w = t.z so that GL clips lines crossing the near plane; y is flipped
// because a window shows GL row 0 at the bottom while image row 0 is the top.
// Injected defines: NEAR_PLANE.

uniform mat4 world_to_camera;
uniform vec2 focal;       // (fx, fy) pixels
uniform vec2 principal;   // (cx, cy) pixels
uniform vec2 image_size;  // (W, H) pixels
uniform float point_size;

in vec3 position;

const float FAR_PLANE = 1000.0;

void main() {
    vec3 t = (world_to_camera * vec4(position, 1.0)).xyz;
    // NDC x = 2 u / W - 1, NDC y = 1 - 2 v / H, each times w = t.z.
    vec2 pixel_times_z = focal * t.xy + principal * t.z;
    vec2 clip_xy = vec2(2.0 * pixel_times_z.x / image_size.x - t.z, t.z - 2.0 * pixel_times_z.y / image_size.y);
    // Standard perspective depth: -w at the near plane, +w at the far plane.
    float clip_z = (t.z * (FAR_PLANE + NEAR_PLANE) - 2.0 * FAR_PLANE * NEAR_PLANE) / (FAR_PLANE - NEAR_PLANE);
    gl_Position = vec4(clip_xy, clip_z, t.z);
    gl_PointSize = point_size;
}
