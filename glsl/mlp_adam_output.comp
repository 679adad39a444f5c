#version 460
// The output layer's parameters, one workgroup per output (sector) k: only
// the transitions through sector k have a gradient there, and mlp_bucket.comp
// listed them in row order; each invocation sums one weight's (or the
// bias's) gradient over that list, in that order every run; then Adam.
// With MLP_DENSE every row has a delta at every output: one invocation per
// four weights of an output (or its bias) sums their gradients over all
// rows, with no lists.

#define MLP_PARAMS_ONLY
#include "shared.h"
#include "mlp.glsl"
#include "adam.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
#ifndef MLP_DENSE
layout(std430, set = 0, binding = B_MLP_BUCKETS) readonly buffer Buckets { uint buckets[]; };
#endif
// Targets (one texel each: sector, target, loss, delta) and activations,
// read as texels: one gather each instead of a loop over lanes.
WORDS(target_texels, B_MLP_TARGETS)
WORDS(act_texels, B_MLP_ACTS)
#ifdef MLP_DENSE
WORDS(dense_texels, B_MLP_DENSE)
#endif

// llvmpipe ends a loop after 65 535 iterations: rows go in blocks.
#define BLOCK 32768u

#ifdef MLP_DENSE
void main() {
    // Invocation i: weights (k, 4q .. 4q + 3) for i < MLP_OUTPUTS * MLP_W4
    // (a texel of activations serves four weights), else output k's bias.
    uint i = gl_GlobalInvocationID.x;
    uint weights = MLP_OUTPUTS * MLP_W4;
    if (i >= weights + MLP_OUTPUTS) {
        return;
    }
    bool is_bias = i >= weights;
    uint k = is_bias ? i - weights : i / MLP_W4;
    uint q = is_bias ? 0u : i - k * MLP_W4;
    uint rows = min(batch.count, push.capacity);
    if (rows == 0u) {
        return;
    }
    vec4 g = vec4(0.0);
    for (uint b = 0u; b < rows; b += BLOCK) {
        for (uint s = b; s < min(b + BLOCK, rows); s++) {
            float delta = MLP_TEXEL_FLOAT(dense_texels, (push.capacity + s) * MLP_OUTPUTS + k);
            uint last4 = (s * MLP_HIDDEN + MLP_HIDDEN - 1u) * MLP_W4;
            vec4 a = uintBitsToFloat(FETCH(act_texels, int(last4 + q)));
            g += delta * (is_bias ? vec4(1.0) : a);
        }
    }
    g /= float(rows);
    uint first = mlp_offset(MLP_HIDDEN);
    if (is_bias) {
        adam_step(first + MLP_OUTPUTS * MLP_WIDTH + k, g.x);
    } else {
        for (uint c = 0u; c < 4u; c++) {
            adam_step(first + k * MLP_WIDTH + 4u * q + c, g[c]);
        }
    }
}
#else
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
            float delta = uintBitsToFloat(FETCH(target_texels, int(s)).w);
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
#endif
