#version 400 core
// gaussian_sprite.frag.glsl with the pixel offset d = pixel centre - (u, v) taken in
// double from the double screen mean, then rounded to float once: the CPU splatter does
// the same (its float offsets come from float64 means relative to a tile corner). The
// rest, alpha = min(ALPHA_MAX, o exp(-0.5 d^T conic d)) and the cut-off, is the twin's.
// Injected defines: ALPHA_MAX, ALPHA_MIN.

flat in dvec2 centre;
flat in vec3 conic;
flat in vec4 color_alpha;
flat in float view_depth;

layout(location = 0) out vec4 accum_color;
layout(location = 1) out vec4 accum_depth;

void main() {
    vec2 d = vec2(dvec2(gl_FragCoord.xy) - centre);
    float power = -0.5 * (conic.x * d.x * d.x + 2.0 * conic.y * d.x * d.y + conic.z * d.y * d.y);
    float alpha = min(ALPHA_MAX, color_alpha.a * exp(power));
    if (alpha < ALPHA_MIN) {
        discard;
    }
    accum_color = vec4(color_alpha.rgb * alpha, alpha);
    accum_depth = vec4(view_depth * alpha, 0.0, 0.0, alpha);
}
