#version 330 core
// Linear blend skinning of the web page's baked avatar (pghm.web.bake), one vertex per
// Gaussian, its outputs captured by transform feedback (the rasteriser is off):
//   M = sum_k w_k B_{j_k}   (B_j: the frame's 3 x 4 bone transforms, up to 4 bones a Gaussian)
//   mu = M (c, 1),   s = exp(log_scale),   rgb = clamp(color, 0, 1),   opacity 1 (PGHM's)
// The frame's canonical point c, log-scale and colour arrive as attributes: the page adds the
// frame's principal components to their means before this pass.
// Injected define: TEXTURE_WIDTH (shaders.source).

uniform sampler2D bones;  // texels 3 j, 3 j + 1, 3 j + 2 (row-major, TEXTURE_WIDTH a row): the rows of B_j

in vec3 canonical;
in float log_scale;
in vec3 color;
in uvec4 bone_index;
in vec4 bone_weight;

out vec4 mean_scale;     // (mu, s), as the sprite shader's mean_scale texel
out vec4 color_opacity;  // (r, g, b, o), as its color_opacity texel

vec4 bone_row(int i) {
    return texelFetch(bones, ivec2(i % TEXTURE_WIDTH, i / TEXTURE_WIDTH), 0);
}

vec3 transformed(uint bone, vec4 point) {
    int first = 3 * int(bone);
    return vec3(dot(bone_row(first), point), dot(bone_row(first + 1), point), dot(bone_row(first + 2), point));
}

void main() {
    vec4 point = vec4(canonical, 1.0);
    vec3 mu = vec3(0.0);
    for (int k = 0; k < 4; ++k) {
        mu += bone_weight[k] * transformed(bone_index[k], point);
    }
    mean_scale = vec4(mu, exp(log_scale));
    color_opacity = vec4(clamp(color, 0.0, 1.0), 1.0);
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);
}
