#version 330 core
// Flat colour of an overlay (alpha-blended over the scene).

uniform vec4 color;

out vec4 fragment;

void main() {
    fragment = color;
}
