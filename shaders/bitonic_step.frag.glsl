#version 330 core
// One compare-exchange step (stage size k, distance j) of a bitonic sorting network over
// (index, key) pairs, ordered by key then index. Every pair is distinct, so the network
// (not stable by itself) gives exactly the stable order of the keys.
// Injected defines: TEXTURE_WIDTH.

uniform sampler2D pairs;  // (index, key) per slot
uniform int stage;        // k: length of the bitonic sequences being merged
uniform int distance;     // j: partner slot is i ^ j

out vec2 index_key;

ivec2 texel(int i) {
    return ivec2(i % TEXTURE_WIDTH, i / TEXTURE_WIDTH);
}

bool before(vec2 p, vec2 q) {
    return p.y < q.y || (p.y == q.y && p.x < q.x);
}

void main() {
    ivec2 slot = ivec2(gl_FragCoord.xy);
    int i = slot.y * TEXTURE_WIDTH + slot.x;
    int partner = i ^ distance;
    vec2 self = texelFetch(pairs, slot, 0).xy;
    vec2 other = texelFetch(pairs, texel(partner), 0).xy;
    // Within an ascending block the lower slot keeps the smaller pair; descending: larger.
    bool keep_smaller = (i < partner) == ((i & stage) == 0);
    index_key = (keep_smaller == before(other, self)) ? other : self;
}
