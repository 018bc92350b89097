#version 330 core
// The skinning pass (web_skinning.vert.glsl) draws nothing; a program still needs a fragment stage.

out vec4 color;

void main() {
    color = vec4(0.0);
}
