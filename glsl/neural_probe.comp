#version 460
// Neural-Q sampling on host-given inputs, for tests: in[0].xyz = a point,
// in[1].xyz = its normal, in[2 + i].xyz = three uniform numbers; out[i] =
// (local direction, mixture pdf) of the mixture at that state.

#include "shared.h"
#include "rng.glsl"
#include "sampling.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

#include "bsdf.glsl"
#include "neural.glsl"
#include "guide.glsl"

layout(std430, set = 0, binding = B_PROBE_IN) readonly buffer ProbeIn { vec4 probe_in[]; };
layout(std430, set = 0, binding = B_PROBE_OUT) writeonly buffer ProbeOut { vec4 probe_out[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.item_count) {
        return;
    }
    GuideVertex g = neural_infer(probe_in[0].xyz, probe_in[1].xyz);
    Bsdf white = bsdf_diffuse(vec3(1.0));
    vec3 wo = vec3(0.0, 0.0, 1.0);
    uint sector;
    float p_sector;
    Mixture m = mixture_one_sided(g, white);
    vec3 w = mixture_sample(m, white, wo, probe_in[2u + i].xyz, sector, p_sector);
    probe_out[i] = vec4(w, mixture_pdf_in(m, white, wo, w, p_sector));
}
