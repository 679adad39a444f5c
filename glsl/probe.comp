#version 460
// Runs the scene's GLSL building blocks on host-given inputs so tests can
// compare them with CPU references: BVH traversal, the hemisphere map and
// the BSDF.
// (sarsa_probe.comp does the same for the Sarsa guide.)

#include "shared.h"
#include "sampling.glsl"
#include "scene.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

#include "bsdf.glsl"

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
        // in = (u, v, grey albedo, 0), wo = the normal; out = (wi, pdf),
        // and out[count + i] = (f cos, reflected estimate of irradiance 1)
        vec4 q = probe_in[i];
        Bsdf bsdf = Bsdf(vec3(q.z));
        vec3 wo = vec3(0.0, 0.0, 1.0);
        vec2 square;
        vec3 wi = bsdf_sample(bsdf, wo, q.xy, square);
        probe_out[i] = vec4(wi, bsdf_pdf(bsdf, wo, wi));
        probe_out[params.item_count + i] = vec4(bsdf_eval(bsdf, wo, wi), bsdf_reflect(bsdf, wo, 1.0));
    }
}
