#version 460
// The output layer's parameters, one workgroup per output (sector) k: only
// the transitions through sector k have a gradient there, and mlp_bucket.comp
// listed them in row order; each invocation sums one weight's (or the
// bias's) gradient over that list, in that order every run; then Adam.

#define MLP_PARAMS_ONLY
#include "shared.h"
#include "mlp.glsl"
#include "adam.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
layout(std430, set = 0, binding = B_MLP_BUCKETS) readonly buffer Buckets { uint buckets[]; };
// Targets (one texel each: sector, target, loss, delta) and activations,
// read as texels: one gather each instead of a loop over lanes.
layout(set = 0, binding = B_MLP_TARGETS) uniform usamplerBuffer target_texels;
layout(set = 0, binding = B_MLP_ACTS) uniform usamplerBuffer act_texels;

// llvmpipe ends a loop after 65 535 iterations: rows go in blocks.
#define BLOCK 32768u

void main() {
    uint k = gl_WorkGroupID.x;
    uint lane = gl_LocalInvocationIndex;
    uint rows = min(batch.count, push.capacity);
    if (rows == 0u) {
        return; // uniform across the workgroup
    }
    // Each invocation owns weights lane, lane + 64, ... and the bias at MLP_WIDTH.
    float g[(MLP_WIDTH + LINEAR_GROUP) / LINEAR_GROUP];
    uint owned = (MLP_WIDTH + LINEAR_GROUP) / LINEAR_GROUP;
    for (uint j = 0u; j < owned; j++) {
        g[j] = 0.0;
    }
    uint list = MLP_OUTPUTS + 2u;
    uint begin = buckets[k];
    uint end = buckets[k + 1u];
    for (uint b = begin; b < end; b += BLOCK) {
        for (uint n = b; n < min(b + BLOCK, end); n++) {
            uint s = buckets[list + n];
            float delta = uintBitsToFloat(texelFetch(target_texels, int(s)).w);
            uint last = (s * MLP_HIDDEN + MLP_HIDDEN - 1u) * MLP_WIDTH;
            for (uint j = 0u; j < owned; j++) {
                uint i = lane + j * LINEAR_GROUP;
                float a = MLP_TEXEL_FLOAT(act_texels, last + min(i, MLP_WIDTH - 1u));
                g[j] += delta * (i < MLP_WIDTH ? a : (i == MLP_WIDTH ? 1.0 : 0.0));
            }
        }
    }
    uint first = mlp_offset(MLP_HIDDEN);
    for (uint j = 0u; j < owned; j++) {
        uint i = lane + j * LINEAR_GROUP;
        if (i < MLP_WIDTH) {
            adam_step(first + k * MLP_WIDTH + i, g[j] / float(rows));
        } else if (i == MLP_WIDTH) {
            adam_step(first + MLP_OUTPUTS * MLP_WIDTH + k, g[j] / float(rows));
        }
    }
}
