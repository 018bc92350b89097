#version 330 core
// First pass of the GPU depth sort: one fragment per slot i of the padded power-of-two
// list writes (index, key). Real Gaussians get key = t.z = (R mu + T).z; padding slots get
// key +inf so they sort after every Gaussian. Indices are exact in float32 below 2^24.
// Injected defines: TEXTURE_WIDTH.

uniform sampler2D mean_scale;  // texel per Gaussian: (mu.x, mu.y, mu.z, s)
uniform vec4 depth_row;        // third row of world_to_camera
uniform int count;             // N

out vec2 index_key;

void main() {
    ivec2 slot = ivec2(gl_FragCoord.xy);
    int i = slot.y * TEXTURE_WIDTH + slot.x;
    float key = uintBitsToFloat(0x7f800000u);
    if (i < count) {
        key = dot(depth_row, vec4(texelFetch(mean_scale, slot, 0).xyz, 1.0));
    }
    index_key = vec2(float(i), key);
}
