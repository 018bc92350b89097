#version 330 core
// Copies the cached scene image into the window's scene viewport (1:1, no filtering).

uniform sampler2D image;

in vec2 uv;
out vec4 color;

void main() {
    color = vec4(texture(image, uv).rgb, 1.0);
}
