#version 400 core
// gaussian_sprite.vert.glsl with the projection in double precision (OpenGL 4.0 /
// GL_ARB_gpu_shader_fp64), as the CPU splatter computes it (float64 per Gaussian). The
// float32 twin loses ~ulp(u) = 6e-5 px of the screen mean at u ~ 1000 px, which moves alpha
// near the 1/255 cut-off by ~6e-5 relative and flips rare (pixel, Gaussian) pairs (up to
// 3.9e-3 in one pixel); in double that error is gone and the fragment shader's offset d is
// exact before it is rounded to float. Formulas and footprint quad: see the float twin.
// Injected defines: NEAR_PLANE, COV_DILATION, ALPHA_MIN, FRUSTUM_CLAMP, TEXTURE_WIDTH. They are
// float literals widened to double here (e.g. 0.3 -> 0.30000001192), 4e-8 relative from the
// splatter's doubles: far below the float32 rounding this shader removes.

uniform sampler2D mean_scale;     // texel per Gaussian: (mu.x, mu.y, mu.z, s)
uniform sampler2D color_opacity;  // texel per Gaussian: (r, g, b, o)
uniform sampler2D draw_order;     // texel k: .r = index of the k-th Gaussian front to back
uniform dmat4 world_to_camera;
uniform dvec2 focal;              // (fx, fy) pixels
uniform dvec2 principal;          // (cx, cy) pixels
uniform vec2 image_size;          // (W, H) pixels

flat out dvec2 centre;            // (u, v) in double: pixel coordinates, row 0 at the top
flat out vec3 conic;              // inverse(cov2d) as (a, b, c), rounded to float once
flat out vec4 color_alpha;        // (r, g, b, o)
flat out float view_depth;        // t.z

ivec2 texel(int i) {
    return ivec2(i % TEXTURE_WIDTH, i / TEXTURE_WIDTH);
}

void cull() {
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    centre = dvec2(0.0);
    conic = vec3(0.0);
    color_alpha = vec4(0.0);
    view_depth = 0.0;
}

void main() {
    int index = int(texelFetch(draw_order, texel(gl_InstanceID), 0).r);
    vec4 ms = texelFetch(mean_scale, texel(index), 0);
    vec4 co = texelFetch(color_opacity, texel(index), 0);
    dvec3 t = (world_to_camera * dvec4(dvec3(ms.xyz), 1.0)).xyz;
    if (t.z <= NEAR_PLANE || co.a < ALPHA_MIN) {
        cull();
        return;
    }

    dvec2 mean2d = focal * t.xy / t.z + principal;
    dvec2 limit = FRUSTUM_CLAMP * dvec2(image_size) / (2.0 * focal);
    dvec2 tc = clamp(t.xy / t.z, -limit, limit) * t.z;
    dvec2 j_diag = focal / t.z;
    dvec2 j_last = -focal * tc / (t.z * t.z);
    double s2 = double(ms.w) * double(ms.w);
    double a = s2 * (j_diag.x * j_diag.x + j_last.x * j_last.x) + COV_DILATION;
    double b = s2 * (j_last.x * j_last.y);
    double c = s2 * (j_diag.y * j_diag.y + j_last.y * j_last.y) + COV_DILATION;
    double det = a * c - b * b;

    // The footprint quad only has to contain the footprint (the fragment shader decides),
    // so it is built in float as in the twin.
    float k = 2.0 * log(co.a / ALPHA_MIN);
    float l00 = sqrt(float(a));
    float l10 = float(b) / l00;
    float l11 = sqrt(max(float(c) - l10 * l10, 0.0));
    vec2 corner = vec2(gl_VertexID & 1, gl_VertexID >> 1) * 2.0 - 1.0;
    vec2 w = corner * (sqrt(k) * 1.001 + 1e-3);
    vec2 pixel = vec2(mean2d) + vec2(l00 * w.x, l10 * w.x + l11 * w.y);

    gl_Position = vec4(2.0 * pixel / image_size - 1.0, 0.0, 1.0);
    centre = mean2d;
    conic = vec3(dvec3(c, -b, a) / det);
    color_alpha = co;
    view_depth = float(t.z);
}
