#version 460
// One Adam step on the whole network, in one dispatch: the first
// HIDDEN_GROUPS workgroups take the hidden layers' parameters, the rest the
// output layer's. They read the batch the training pass left and write
// disjoint parameters, so one dispatch serves both (two before: measured in
// docs/guides.md).
//
// Hidden layers: the gradient, the mean over the batch of delta (unit) x
// activation (input), then an Adam step. Output layer: one workgroup per
// output (sector) k: only the transitions through sector k have a gradient
// there, and mlp_bucket.comp listed them in row order; each invocation sums
// one weight's (or the bias's) gradient over that list, in that order every
// run; then Adam. With MLP_DENSE every row has a delta at every output: one
// invocation per four weights of an output (or its bias) sums their
// gradients over all rows, with no lists.

#define MLP_PARAMS_ONLY
#include "shared.h"
#include "mlp.glsl"
#include "adam.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
#ifndef MLP_DENSE
layout(std430, set = 0, binding = B_MLP_BUCKETS) readonly buffer Buckets { uint buckets[]; };
#endif
// The batch's inputs, activations, deltas and targets (one texel each:
// sector, target, loss, delta), read as texels of four floats: lavapipe
// reads a storage buffer with a loop over lanes, a texel buffer with one
// gather.
WORDS(input_texels, B_MLP_INPUTS)
WORDS(act_texels, B_MLP_ACTS)
WORDS(delta_texels, B_MLP_DELTAS)
WORDS(target_texels, B_MLP_TARGETS)
#ifdef MLP_DENSE
WORDS(dense_texels, B_MLP_DENSE)
#endif

uint unit_index(uint s, uint l, uint o) {
    return (s * MLP_HIDDEN + l) * MLP_WIDTH + o;
}

// Invocations of layer l: one per four weights of a unit (a row's inputs
// are read a texel at a time, so each read serves four weights), then one
// per unit's bias. Where layer l's start.
uint slot_offset(uint l) {
    return l == 0u ? 0u : MLP_WIDTH * (MLP_IN4 + 1u) + (l - 1u) * MLP_WIDTH * (MLP_W4 + 1u);
}

// The hidden layers' invocation p.
void adam_hidden(uint p) {
    uint rows = min(batch.count, push.capacity);
    if (p >= slot_offset(MLP_HIDDEN) || rows == 0u) {
        return;
    }
    uint l = 0u;
    while (p >= slot_offset(l + 1u)) {
        l++;
    }
    uint in4 = mlp_fan_in(l) / 4u;
    uint local_index = p - slot_offset(l);
    bool is_bias = local_index >= MLP_WIDTH * in4;
    uint o = is_bias ? local_index - MLP_WIDTH * in4 : local_index / in4;
    uint q = is_bias ? 0u : local_index - o * in4;

    vec4 g = vec4(0.0);
    for (uint s = 0u; s < rows; s++) {
        float delta = MLP_TEXEL_FLOAT(delta_texels, unit_index(s, l, o));
        uvec4 a = l == 0u ? FETCH(input_texels, int(s * MLP_IN4 + q))
                          : FETCH(act_texels, int(unit_index(s, l - 1u, 0u) / 4u + q));
        g += delta * (is_bias ? vec4(1.0) : uintBitsToFloat(a));
    }
    g /= float(rows);
    if (is_bias) {
        adam_step(mlp_offset(l) + MLP_WIDTH * mlp_fan_in(l) + o, g.x);
    } else {
        uint w = mlp_offset(l) + o * mlp_fan_in(l) + 4u * q;
        for (uint c = 0u; c < 4u; c++) {
            adam_step(w + c, g[c]);
        }
    }
}

// llvmpipe ends a loop after 65 535 iterations: rows go in blocks.
#define BLOCK 32768u

#ifdef MLP_DENSE
// The output layer's invocation i: weights (k, 4q .. 4q + 3) for
// i < MLP_OUTPUTS * MLP_W4 (a texel of activations serves four weights),
// else output k's bias.
void adam_output(uint i) {
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
// The output layer's workgroup k, invocation `lane`.
void adam_output(uint k, uint lane) {
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

// Workgroups of the hidden layers' invocations (Network::record_step
// dispatches these and the output layer's).
uint hidden_groups() {
    return (slot_offset(MLP_HIDDEN) + LINEAR_GROUP - 1u) / LINEAR_GROUP;
}

void main() {
    uint lane = gl_LocalInvocationIndex;
    uint hidden = hidden_groups();
    if (gl_WorkGroupID.x < hidden) {
        adam_hidden(gl_GlobalInvocationID.x);
        return;
    }
    uint group = gl_WorkGroupID.x - hidden;
#ifdef MLP_DENSE
    adam_output(group * LINEAR_GROUP + lane);
#else
    adam_output(group, lane);
#endif
}
