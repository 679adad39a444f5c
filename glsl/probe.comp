#version 460
// Runs the scene's GLSL building blocks on host-given inputs so tests can
// compare them with CPU references: BVH traversal, the hemisphere map, the
// BSDF and its textures, the environment.
// (sarsa_probe.comp does the same for the Sarsa guide.)

#include "shared.h"
#include "sampling.glsl"
#include "scene.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

#include "bsdf.glsl"
#include "texture.glsl"
#include "environment.glsl"

layout(std430, set = 0, binding = B_PROBE_IN) readonly buffer ProbeIn { vec4 probe_in[]; };
layout(std430, set = 0, binding = B_PROBE_OUT) writeonly buffer ProbeOut { vec4 probe_out[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.item_count) {
        return;
    }
    if (params.selector == PROBE_TRACE) {
        // in[2i] = origin, in[2i+1] = direction; out = (t, triangle bits, any-hit flag, 0)
        vec3 o = probe_in[2u * i].xyz;
        vec3 d = probe_in[2u * i + 1u].xyz;
        Hit h = trace_ray(o, d, FAR);
        probe_out[i] = vec4(h.t, uintBitsToFloat(h.triangle), occluded(o, d, FAR) ? 1.0 : 0.0, 0.0);
    } else if (params.selector == PROBE_HEMISPHERE) {
        // in = (u, v, grid a, grid b); out = (direction, sector of that direction)
        vec4 q = probe_in[i];
        vec3 w = square_to_hemisphere(q.xy);
        uint sector = hemisphere_sector(w, uint(q.z), uint(q.w));
        probe_out[i] = vec4(w, float(sector));
    } else if (params.selector == PROBE_BSDF) {
        // in[6i..6i+4] = a Material; in[6i+4] = (wo, front side? 1 : 0);
        // in[6i+5] = three uniform numbers. out[i] = (wi, pdf), out[count + i]
        // = (f cos at wi, reflected estimate of irradiance 1), or for a delta
        // lobe (wi, 0) and (its weight, 0); out[2 count + i] = (the delta
        // lobe's weight, bsdf_delta_share), for a plastic's coat.
        uint b = 6u * i;
        Material m = Material(probe_in[b], probe_in[b + 1u], probe_in[b + 2u], probe_in[b + 3u]);
        vec4 side = probe_in[b + 4u];
        vec3 u = probe_in[b + 5u].xyz;
        Bsdf bsdf = bsdf_of(m, side.w > 0.5);
        // An anisotropic BSDF's tangent, at angle in[6i+5].w.
        bsdf.tangent = vec2(cos(probe_in[b + 5u].w), sin(probe_in[b + 5u].w));
        vec3 wo = side.xyz;
        vec3 delta_weight = vec3(0.0);
        if (bsdf_delta_share(bsdf, wo) > 0.0) {
            bsdf_sample_delta(bsdf, wo, u.z, delta_weight);
        }
        probe_out[2u * params.item_count + i] = vec4(delta_weight, bsdf_delta_share(bsdf, wo));
        if (bsdf_is_delta(bsdf)) {
            vec3 weight;
            vec3 wi = bsdf_sample_delta(bsdf, wo, u.z, weight);
            probe_out[i] = vec4(wi, 0.0);
            probe_out[params.item_count + i] = vec4(weight, 0.0);
        } else {
            vec2 square;
            vec3 wi = bsdf_sample(bsdf, wo, u, square);
            probe_out[i] = vec4(wi, bsdf_pdf(bsdf, wo, wi));
            probe_out[params.item_count + i] = vec4(bsdf_eval(bsdf, wo, wi), bsdf_reflect(bsdf, wo, 1.0));
        }
    } else if (params.selector == PROBE_TEXTURE) {
        // in[5i..5i+4] = a Material; in[5i+4] = (u, v, front side? 1 : 0, 0).
        // out[i] = (its textured BSDF's colour, alpha), out[count + i] =
        // (its second colour, its alpha across its tangent), out[2 count +
        // i] = (its ior_k, 0), out[3 count + i] = (its table and flags as
        // floats, 0, 0): a principled lobe's further weights (clearcoat
        // gloss and spec_trans).
        uint b = 5u * i;
        Material m = Material(probe_in[b], probe_in[b + 1u], probe_in[b + 2u], probe_in[b + 3u]);
        vec4 at = probe_in[b + 4u];
        bool front = at.z > 0.5;
        Bsdf bsdf = bsdf_textured(bsdf_of(m, front), m, front, 0u, vec2(0.0), at.xy);
        probe_out[i] = vec4(bsdf.color, bsdf.alpha);
        probe_out[params.item_count + i] = vec4(bsdf.ior_eta, bsdf.alpha_v);
        probe_out[2u * params.item_count + i] = vec4(bsdf.ior_k, 0.0);
        probe_out[3u * params.item_count + i] = vec4(uintBitsToFloat(bsdf.table), uintBitsToFloat(bsdf.flags), 0.0, 0.0);
    } else if (params.selector == PROBE_ENVIRONMENT) {
        // in[2i] = a direction, in[2i+1] = four uniform numbers. out[i] =
        // (its radiance, its density); out[count + i] = (the direction they
        // draw, its density); out[2 count + i] = (the radiance there, the
        // density looked up there).
        // The part is drawn by power with u.x, which then picks the cell.
        vec3 d = probe_in[2u * i].xyz;
        uint part;
        probe_out[i] = vec4(environment_eval(d), environment_pdf(d, part));
        vec4 u = probe_in[2u * i + 1u];
        float share = environment_share(0u);
        part = u.x < share || environment_parts() == 1u ? 0u : 1u;
        u.x = min(part == 0u ? u.x / share : (u.x - share) / environment_share(1u), 0.99999994);
        float pdf;
        vec3 w = environment_sample(u, part, pdf);
        probe_out[params.item_count + i] = vec4(w, pdf);
        probe_out[2u * params.item_count + i] = vec4(environment_eval(w), environment_pdf(w, part));
    }
}
