#version 460
// Before the output layer's Adam step: the batch's rows grouped by sector,
// each group in row order, by a stable counting sort in one invocation (a
// batch is a few thousand rows; every sector's workgroup scanning the whole
// batch for its rows cost 144 times that). Layout of the buckets buffer:
// [0, n + 1]: sector k's rows are entries buckets[k] .. buckets[k + 1] - 1
// of the list, which starts at n + 2.

#define MLP_PARAMS_ONLY
#include "shared.h"
#include "mlp.glsl"

layout(local_size_x = 1) in;

layout(push_constant) uniform Push { MlpPush push; };
layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
layout(std430, set = 0, binding = B_MLP_TARGETS) readonly buffer Targets { MlpTarget targets[]; };
layout(std430, set = 0, binding = B_MLP_BUCKETS) buffer Buckets { uint buckets[]; };

// llvmpipe ends a loop after 65 535 iterations: rows go in blocks.
#define BLOCK 32768u

void main() {
    uint rows = min(batch.count, push.capacity);
    uint list = MLP_OUTPUTS + 2u;
    for (uint k = 0u; k < MLP_OUTPUTS + 2u; k++) {
        buckets[k] = 0u;
    }
    // Counts at k + 2; their running sum leaves sector k's start at k + 1.
    for (uint b = 0u; b < rows; b += BLOCK) {
        for (uint s = b; s < min(b + BLOCK, rows); s++) {
            buckets[targets[s].sector + 2u] += 1u;
        }
    }
    for (uint k = 2u; k < MLP_OUTPUTS + 2u; k++) {
        buckets[k] += buckets[k - 1u];
    }
    // Placing a row moves its sector's cursor on: at the end, entry k + 1
    // holds sector k's end, the start of sector k + 1.
    for (uint b = 0u; b < rows; b += BLOCK) {
        for (uint s = b; s < min(b + BLOCK, rows); s++) {
            uint k = targets[s].sector;
            buckets[list + buckets[k + 1u]] = s;
            buckets[k + 1u] += 1u;
        }
    }
}
