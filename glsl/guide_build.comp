#version 460
// Per volume, after a pass that learned (FLAG_LEARN): folds the targets the
// pass accumulated into Q. With alpha = 1 / (1 + visits), Q is the running
// mean of its targets, so Q <- (Q N + sum) / (N + count); the share NEE
// carries likewise. Then, always: the irradiance-like sum the Sarsa target needs,
// (2 pi / n) sum_j Q_j cos(theta_j), the total weight of its distribution
// (with P(k), it gives back Q(v, k) without reading Q), and the distribution over
// sectors (proportional to Q, or to Q cos(theta) with FLAG_COS_DISTRIBUTION)
// as an alias table, so a sample costs one read instead of a CDF search.

#include "shared.h"
#include "atomics.glsl"
#include "sampling.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };
layout(std430, set = 0, binding = B_Q) buffer QValues { float q_values[]; };
layout(std430, set = 0, binding = B_Q_DIRECT) buffer QDirect { float q_direct[]; };
// The pass's tallies, as the trace kernel's atomics wrote them (float
// atomics and the CAS fallback write the same bits).
layout(std430, set = 0, binding = B_SUM) buffer TargetSums { TALLY target_sum[]; };
layout(std430, set = 0, binding = B_DIRECT_SUM) buffer DirectSums { TALLY direct_sum[]; };
layout(std430, set = 0, binding = B_VISITS) buffer Visits { uint visits[]; };
layout(std430, set = 0, binding = B_VISITS_TOTAL) buffer VisitsTotal { uint visits_total[]; };

// Folds cell i's tallies of the pass into its running means.
void fold(uint i) {
    uint count = visits[i];
    if (count == 0u) {
        return;
    }
    uint seen = visits_total[i];
    q_values[i] = (q_values[i] * float(seen) + TALLY_VALUE(target_sum[i])) / float(seen + count);
    q_direct[i] = (q_direct[i] * float(seen) + TALLY_VALUE(direct_sum[i])) / float(seen + count);
    direct_sum[i] = TALLY_ZERO;
    target_sum[i] = TALLY_ZERO;
    visits_total[i] = seen + count;
    visits[i] = 0u;
}
layout(std430, set = 0, binding = B_SECTORS) buffer Sectors { SectorEntry sectors[]; };
layout(std430, set = 0, binding = B_VOLUME_SUMS) writeonly buffer VolumeSums { vec2 volume_sums[]; };

// First index from `from` on whose column is short of (or, with `large`, at
// least) one sector's worth, n if none.
uint next_column(uint base, uint from, uint n, bool large) {
    while (from < n && (sectors[base + from].threshold >= 1.0) != large) {
        ++from;
    }
    return from;
}

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= params.volume_count) {
        return;
    }
    uint a = params.sector_grid & 0xffffu;
    uint b = params.sector_grid >> 16;
    uint n = a * b;
    uint base = v * n;
    bool cos_weighted = (params.flags & FLAG_COS_DISTRIBUTION) != 0u;
    bool nee = (params.flags & FLAG_NEE) != 0u;
    bool learned = (params.flags & FLAG_LEARN) != 0u;
    float weighted = 0.0;
    float total = 0.0;
    for (uint k = 0u; k < n; ++k) {
        if (learned) {
            fold(base + k);
        }
        float cos_k = sector_cos(k, a, b);
        float q = max(q_values[base + k], 0.0);
        weighted += q * cos_k;
        // With NEE, scattering should find what NEE does not already carry.
        float qs = nee ? max(q - q_direct[base + k], 0.0) : q;
        float w = cos_weighted ? qs * cos_k : qs;
        total += w;
        sectors[base + k].p = w;
    }
    volume_sums[v] = vec2(weighted * 2.0 * PI / float(n), total);
    for (uint k = 0u; k < n; ++k) {
        // An all-zero volume samples sectors uniformly.
        float p = total > 0.0 ? sectors[base + k].p / total : 1.0 / float(n);
        sectors[base + k] = SectorEntry(p * float(n), k, p, p);
    }

    // Vose's alias construction as one sweep without work lists: short
    // columns are filled in index order, each from the current tall column l,
    // which moves on once it has become short itself. A column that becomes
    // short behind the sweep is filled next; one ahead of it, when reached.
    uint s = next_column(base, 0u, n, false);
    uint l = next_column(base, 0u, n, true);
    uint short_column = s;
    while (short_column < n && l < n) {
        float missing = 1.0 - sectors[base + short_column].threshold;
        sectors[base + short_column].alias = l;
        float left = sectors[base + l].threshold - missing;
        sectors[base + l].threshold = left;
        if (left < 1.0) {
            uint now_short = l;
            l = next_column(base, l + 1u, n, true);
            if (now_short < s) {
                short_column = now_short;
                continue;
            }
        }
        s = next_column(base, s + 1u, n, false);
        short_column = s;
    }
    // Columns left over hold one sector's worth up to rounding: they keep
    // themselves (alias k) or, at threshold >= 1, always do.
    for (uint k = 0u; k < n; ++k) {
        sectors[base + k].p_alias = sectors[base + sectors[base + k].alias].p;
    }
}
