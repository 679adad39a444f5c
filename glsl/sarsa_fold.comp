#version 460
// Folds the targets a sample pass accumulated into Q: with alpha = 1 / (1 + visits)
// Q is the running mean of its targets, so Q <- (Q N + sum) / (N + count).

#include "shared.h"
#include "atomics.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };
layout(std430, set = 0, binding = B_Q) buffer QValues { float q_values[]; };
// 64-bit fixed point (FIXED_ATOMICS), else float: written as float by
// atomicAdd or as float bits by the CAS fallback, the same bits.
#ifdef FIXED_ATOMICS
layout(std430, set = 0, binding = B_SUM) buffer TargetSums { uint64_t target_sum[]; };
layout(std430, set = 0, binding = B_DIRECT_SUM) buffer DirectSums { uint64_t direct_sum[]; };
#define TALLY_VALUE(t) from_fixed(t)
#define TALLY_ZERO uint64_t(0)
#else
layout(std430, set = 0, binding = B_SUM) buffer TargetSums { float target_sum[]; };
layout(std430, set = 0, binding = B_DIRECT_SUM) buffer DirectSums { float direct_sum[]; };
#define TALLY_VALUE(t) (t)
#define TALLY_ZERO 0.0
#endif
layout(std430, set = 0, binding = B_VISITS) buffer Visits { uint visits[]; };
layout(std430, set = 0, binding = B_VISITS_TOTAL) buffer VisitsTotal { uint visits_total[]; };
// The running mean of the part of the targets NEE carries (see sarsa.glsl).
layout(std430, set = 0, binding = B_Q_DIRECT) buffer QDirect { float q_direct[]; };

void main() {
    // Grid-stride loop: volumes x sectors may exceed one dispatch dimension.
    uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    for (uint i = gl_GlobalInvocationID.x; i < params.item_count; i += stride) {
        uint count = visits[i];
        if (count == 0u) {
            continue;
        }
        uint seen = visits_total[i];
        q_values[i] = (q_values[i] * float(seen) + TALLY_VALUE(target_sum[i])) / float(seen + count);
        q_direct[i] = (q_direct[i] * float(seen) + TALLY_VALUE(direct_sum[i])) / float(seen + count);
        direct_sum[i] = TALLY_ZERO;
        visits_total[i] = seen + count;
        target_sum[i] = TALLY_ZERO;
        visits[i] = 0u;
    }
}
