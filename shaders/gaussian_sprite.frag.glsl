#version 330 core
// alpha = min(ALPHA_MAX, o exp(-0.5 d^T conic d)), d = pixel centre - (u, v); fragments
// with alpha < ALPHA_MIN are discarded. Outputs are premultiplied so that the blend
// (ONE_MINUS_DST_ALPHA, ONE) composites front to back:
//   dst.rgb += (1 - dst.a) c alpha,  dst.a += (1 - dst.a) alpha,  and T_i = 1 - dst.a.
// The offset d is taken in `real` from the vertex shader's screen mean, then rounded to
// float once: in double the CPU splatter does the same (its float offsets come from float64
// means relative to a tile corner); in float the conversions are identities. The rest is
// float in either precision.
// Injected defines: ALPHA_MAX, ALPHA_MIN, and the precision type real2 (shaders.source).

flat in real2 centre;
flat in vec3 conic;
flat in vec4 color_alpha;
flat in float view_depth;

layout(location = 0) out vec4 accum_color;  // (sum c alpha T, 1 - T)
layout(location = 1) out vec4 accum_depth;  // (sum z alpha T, 0, 0, 1 - T); unused if unbound

void main() {
    vec2 d = vec2(real2(gl_FragCoord.xy) - centre);
    float power = -0.5 * (conic.x * d.x * d.x + 2.0 * conic.y * d.x * d.y + conic.z * d.y * d.y);
    float alpha = min(ALPHA_MAX, color_alpha.a * exp(power));
    if (alpha < ALPHA_MIN) {
        discard;
    }
    accum_color = vec4(color_alpha.rgb * alpha, alpha);
    accum_depth = vec4(view_depth * alpha, 0.0, 0.0, alpha);
}
