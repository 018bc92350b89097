#version 330 core
// Lit, textured body surface for the synthetic data (pghm.synth.render).
//
// Shading (linear light, textures and output in sRGB approximated by gamma 2.2):
//   h      = sum_k a_k G_k(uv)                    pose-dependent fold height in [-1, 1]
//   n'     = bump(n, BUMP_DEPTH h)                 surface-gradient bump mapping [Mikkelsen 2010]
//   rho    = albedo (1 - FOLD_DARKENING max(-h, 0))  fold valleys are darker
//   colour = rho (ambient (HEMI_GROUND + (1 - HEMI_GROUND) (1 + n'.y) / 2) + max(n'.l, 0) c)
//          + specular_strength max(n'.h, 0)^shininess c [n'.l > 0]  (Blinn-Phong)
// with l the unit direction towards the light, h_v the half vector of l and the view.
// Injected defines: BUMP_DEPTH, FOLD_DARKENING, HEMI_GROUND.

in vec3 v_world;
in vec3 v_normal;
centroid in vec2 v_uv;

uniform sampler2D albedo_map;    // rgb: sRGB albedo, a: specular strength
uniform sampler2D wrinkle_map0;  // fold patterns G_0..G_3
uniform sampler2D wrinkle_map1;  // fold patterns G_4..G_7
uniform vec4 wrinkle_amplitude0; // a_0..a_3, from the joints' bend angles
uniform vec4 wrinkle_amplitude1; // a_4..a_7
uniform vec3 camera_centre;
uniform vec3 light_direction;    // unit, towards the light
uniform vec3 light_colour;
uniform float ambient;
uniform float shininess;
uniform int albedo_only;         // 1: output the static texture, unlit and without folds

out vec4 frag_colour;

const float GAMMA = 2.2;
const float DEGENERATE = 1e-20;

vec3 bump(vec3 n, float height) {
    // Mikkelsen, "Bump Mapping Unparametrized Surfaces on the GPU" (2010): the surface
    // gradient of a height field from screen-space derivatives, no tangent frame needed.
    vec3 dpdx = dFdx(v_world);
    vec3 dpdy = dFdy(v_world);
    vec3 r1 = cross(dpdy, n);
    vec3 r2 = cross(n, dpdx);
    float det = dot(dpdx, r1);
    if (abs(det) < DEGENERATE) {
        return n;
    }
    vec3 grad = sign(det) * (dFdx(height) * r1 + dFdy(height) * r2);
    return normalize(abs(det) * n - grad);
}

void main() {
    vec4 texel = texture(albedo_map, v_uv);
    if (albedo_only == 1) {
        frag_colour = vec4(texel.rgb, 1.0);
        return;
    }
    float h = dot(texture(wrinkle_map0, v_uv), wrinkle_amplitude0)
            + dot(texture(wrinkle_map1, v_uv), wrinkle_amplitude1);
    vec3 view = normalize(camera_centre - v_world);
    vec3 n = normalize(v_normal);
    // Two-sided: the inside of a sleeve or skirt is lit like its outside.
    if (dot(n, view) < 0.0) {
        n = -n;
    }
    n = bump(n, BUMP_DEPTH * h);
    vec3 albedo = pow(texel.rgb, vec3(GAMMA)) * (1.0 - FOLD_DARKENING * max(-h, 0.0));
    float lambert = max(dot(n, light_direction), 0.0);
    vec3 half_vector = normalize(light_direction + view);
    float specular = lambert > 0.0 ? pow(max(dot(n, half_vector), 0.0), shininess) : 0.0;
    float sky = HEMI_GROUND + (1.0 - HEMI_GROUND) * 0.5 * (1.0 + n.y);
    vec3 linear = albedo * (ambient * sky + lambert * light_colour) + texel.a * specular * light_colour;
    frag_colour = vec4(pow(clamp(linear, 0.0, 1.0), vec3(1.0 / GAMMA)), 1.0);
}
