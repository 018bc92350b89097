#version 330 core
// One screen-space quad per isotropic 3D Gaussian (instanced, 4 vertices as a strip).
// Projection, 2D covariance and conic follow the CPU splatter's spec (pghm.splat):
//   t = R mu + T;  u = fx t.x / t.z + cx,  v = fy t.y / t.z + cy
//   cov2d = s^2 J J^T + COV_DILATION I,  J = [[fx/z, 0, -fx x'/z^2], [0, fy/z, -fy y'/z^2]]
//   x' = clamp(t.x / t.z, -FRUSTUM_CLAMP W / (2 fx), +FRUSTUM_CLAMP W / (2 fx)) t.z  (J only)
// Injected defines: NEAR_PLANE, COV_DILATION, ALPHA_MIN, FRUSTUM_CLAMP, TEXTURE_WIDTH, and the
// precision types real, real2, real3, real4, realmat4 (shaders.source(..., precision=...)).
//
// Primitive. By default one instanced quad per Gaussian (gl_InstanceID, 4 strip vertices).
// With PGHM_POINTS defined, one GL point per Gaussian (gl_VertexID): the square of side
// 2 e sqrt(max(a, c)) around (u, v) holds the footprint's bounding box. Fragments are
// identical; llvmpipe sets up one point faster than two triangles. GL clips a point by its
// centre, so the caller widens the viewport by `guard` pixels on every side (the largest
// point half side) and scissors to the image: a point whose centre is off the image but
// whose square reaches into it is still drawn. gl_FragCoord stays the image pixel.
// With PGHM_TRIANGLES defined, the quad is two triangles of a plain (not instanced) draw of 6
// vertices a Gaussian (gl_VertexID / 6): SwiftShader, a browser's software WebGL, runs each
// instance of an instanced draw as a draw of its own (the web page, pghm.web).
//
// Precision. The projection, t through the conic, is computed in `real`: float (#version
// 330 core) or double (#version 400 core: OpenGL 4.0 / GL_ARB_gpu_shader_fp64), the latter
// as the CPU splatter computes it (float64 per Gaussian). In float the screen mean loses
// ~ulp(u) = 6e-5 px at u ~ 1000 px, which moves alpha near the 1/255 cut-off by ~6e-5
// relative and flips rare (pixel, Gaussian) pairs (up to 3.9e-3 in one pixel); in double
// that error is gone and the fragment shader's offset d is exact before it is rounded to
// float. The conversions to and from `real` below are identities in float. In double the
// injected defines are float literals widened to double (e.g. 0.3 -> 0.30000001192), 4e-8
// relative from the splatter's doubles: far below the float32 rounding double removes.

uniform sampler2D mean_scale;     // texel per Gaussian: (mu.x, mu.y, mu.z, s)
uniform sampler2D color_opacity;  // texel per Gaussian: (r, g, b, o)
uniform sampler2D draw_order;     // texel k: .r = index of the k-th Gaussian front to back
uniform realmat4 world_to_camera;
uniform real2 focal;              // (fx, fy) pixels
uniform real2 principal;          // (cx, cy) pixels
uniform vec2 image_size;          // (W, H) pixels
uniform float guard;              // pixels the viewport extends past the image on every side

flat out real2 centre;            // (u, v): pixel coordinates, row 0 at the top
flat out vec3 conic;              // inverse(cov2d) as (a, b, c) of [[a, b], [b, c]], rounded to float once
flat out vec4 color_alpha;        // (r, g, b, o)
flat out float view_depth;        // t.z

ivec2 texel(int i) {
    return ivec2(i % TEXTURE_WIDTH, i / TEXTURE_WIDTH);
}

void cull() {
    // All four corners on one point outside the clip volume: no fragment is generated.
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    centre = real2(0.0);
    conic = vec3(0.0);
    color_alpha = vec4(0.0);
    view_depth = 0.0;
}

vec4 pixel_to_clip(vec2 pixel) {
    return vec4(2.0 * (pixel + guard) / (image_size + 2.0 * guard) - 1.0, 0.0, 1.0);
}

void main() {
#if defined(PGHM_POINTS)
    int sprite = gl_VertexID;
#elif defined(PGHM_TRIANGLES)
    int sprite = gl_VertexID / 6;
#else
    int sprite = gl_InstanceID;
#endif
    int index = int(texelFetch(draw_order, texel(sprite), 0).r);
    vec4 ms = texelFetch(mean_scale, texel(index), 0);
    vec4 co = texelFetch(color_opacity, texel(index), 0);
    real3 t = (world_to_camera * real4(real3(ms.xyz), 1.0)).xyz;
    // o < ALPHA_MIN: alpha = o exp(-q/2) never reaches ALPHA_MIN, so the Gaussian is invisible.
    if (t.z <= NEAR_PLANE || co.a < ALPHA_MIN) {
        cull();
        return;
    }

    real2 mean2d = focal * t.xy / t.z + principal;
    real2 limit = FRUSTUM_CLAMP * real2(image_size) / (2.0 * focal);
    real2 tc = clamp(t.xy / t.z, -limit, limit) * t.z;
    // J's two non-zero entries per row: (fx/z, -fx x'/z^2) and (fy/z, -fy y'/z^2).
    real2 j_diag = focal / t.z;
    real2 j_last = -focal * tc / (t.z * t.z);
    real s2 = real(ms.w) * real(ms.w);
    real a = s2 * (j_diag.x * j_diag.x + j_last.x * j_last.x) + COV_DILATION;
    real b = s2 * (j_last.x * j_last.y);
    real c = s2 * (j_diag.y * j_diag.y + j_last.y * j_last.y) + COV_DILATION;
    real det = a * c - b * b;

    // alpha >= ALPHA_MIN  <=>  d^T conic d <= k = 2 ln(o / ALPHA_MIN): the ellipse
    // { L w sqrt(k) : |w| <= 1 } with cov2d = L L^T (Cholesky). The unit square [-1, 1]^2
    // mapped by L sqrt(k) is a parallelogram circumscribing it with the least area
    // (4 k sqrt(det)), no eigen-decomposition needed. The 1.001 and 1e-3 margins keep
    // pixel centres on the boundary inside despite float rounding; the fragment shader
    // applies the exact test. The quad only has to contain the footprint, so it is built
    // in float in either precision.
    float k = 2.0 * log(co.a / ALPHA_MIN);
    float e = sqrt(k) * 1.001 + 1e-3;
    // No y flip: GL window row r holds image row r, so the read-back buffer (bottom row
    // first) is the image top row first, and gl_FragCoord.xy is the spec's pixel centre.
#ifdef PGHM_POINTS
    gl_PointSize = 2.0 * e * sqrt(float(max(a, c)));
    gl_Position = pixel_to_clip(vec2(mean2d));
#else
    float l00 = sqrt(float(a));
    float l10 = float(b) / l00;
    float l11 = sqrt(max(float(c) - l10 * l10, 0.0));
#ifdef PGHM_TRIANGLES
    int vertex = gl_VertexID % 6;  // triangles (0, 1, 2) and (2, 1, 3) of the strip's corners
    int corner = vertex < 3 ? vertex : (vertex == 5 ? 3 : 5 - vertex);
#else
    int corner = gl_VertexID;
#endif
    vec2 w = (vec2(corner & 1, corner >> 1) * 2.0 - 1.0) * e;
    gl_Position = pixel_to_clip(vec2(mean2d) + vec2(l00 * w.x, l10 * w.x + l11 * w.y));
#endif
    centre = mean2d;
    conic = vec3(real3(c, -b, a) / det);
    color_alpha = co;
    view_depth = float(t.z);
}
