#version 460
// The output layer's parameters, one workgroup per output (sector) k: only
// the transitions through sector k have a gradient there, so the workgroup
// first lists them (in row order), a chunk of the batch at a time, then each invocation
// sums one weight's (or the bias's) gradient over the list; then Adam.

#define MLP_PARAMS_ONLY
#include "shared.h"
#include "mlp.glsl"
#include "adam.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
layout(std430, set = 0, binding = B_MLP_TARGETS) readonly buffer Targets { MlpTarget targets[]; };
layout(std430, set = 0, binding = B_MLP_ACTS) readonly buffer Acts { float acts[]; };

#define CHUNK (16 * LINEAR_GROUP)
shared uint listed;
shared uint list[CHUNK];

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
    for (uint base = 0u; base < rows; base += CHUNK) {
        // One invocation lists the chunk's rows through sector k in row
        // order: sums over the list then add in the same order every run.
        if (lane == 0u) {
            uint n = 0u;
            for (uint s = base; s < min(base + CHUNK, rows); ++s) {
                if (targets[s].sector == k) {
                    list[n] = s;
                    n += 1u;
                }
            }
            listed = n;
        }
        barrier();
        for (uint n = 0u; n < listed; n++) {
            uint s = list[n];
            float delta = targets[s].delta;
            uint last = (s * MLP_HIDDEN + MLP_HIDDEN - 1u) * MLP_WIDTH;
            for (uint j = 0u; j < owned; j++) {
                uint i = lane + j * LINEAR_GROUP;
                if (i < MLP_WIDTH) {
                    g[j] += delta * acts[last + i];
                } else if (i == MLP_WIDTH) {
                    g[j] += delta;
                }
            }
        }
        barrier();
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
