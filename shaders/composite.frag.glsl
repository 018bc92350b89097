#version 330 core
// The background under the accumulated sprites: C + (1 - A) background.
// The accumulation holds image row 0 in GL row 0 (see gaussian_sprite.vert.glsl); a window
// shows GL row 0 at the bottom, so flip_y turns the image upright for presentation.

uniform sampler2D accum;  // (C, A) = (sum c alpha T, 1 - T_N)
uniform vec3 background;
uniform bool flip_y;
uniform bool opaque;      // write alpha 1 (presentation) instead of A (read-back)

in vec2 uv;
out vec4 color;

void main() {
    vec4 c = texture(accum, flip_y ? vec2(uv.x, 1.0 - uv.y) : uv);
    color = vec4(c.rgb + (1.0 - c.a) * background, opaque ? 1.0 : c.a);
}
