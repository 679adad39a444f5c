#version 460
// Neural-Q sampling on host-given inputs, for tests: in[0].xyz = a point,
// in[1].xyz = its normal, in[2 + i].xyz = three uniform numbers; out[i] =
// (local direction, mixture pdf) of neural_sample at that state.

#include "shared.h"
#include "sampling.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

#include "neural.glsl"

layout(std430, set = 0, binding = B_PROBE_IN) readonly buffer ProbeIn { vec4 probe_in[]; };
layout(std430, set = 0, binding = B_PROBE_OUT) writeonly buffer ProbeOut { vec4 probe_out[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.item_count) {
        return;
    }
    float total = neural_infer(probe_in[0].xyz, probe_in[1].xyz).x;
    uint sector;
    float p_sector;
    vec3 w = neural_sample(total, probe_in[2u + i].xyz, sector, p_sector);
    probe_out[i] = vec4(w, neural_mixture_pdf(total, p_sector, w.z));
}
