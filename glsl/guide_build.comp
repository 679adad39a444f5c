#version 460
// Per volume, after a pass that learned (FLAG_LEARN): folds the targets the
// pass accumulated into Q. With alpha = 1 / (1 + visits), Q is the running
// mean of its targets, so Q <- (Q N + sum) / (N + count); the share NEE
// carries likewise. Then, always: the irradiance-like sum the Sarsa target needs,
// (2 pi / n) sum_j Q_j cos(theta_j) (with FLAG_MAX_TARGET, which only Neural-Q
// sets, max_j Q_j cos(theta_j)), the total weight of its distribution
// (with P(k), it gives back Q(v, k) without reading Q), and the distribution over
// sectors (proportional to Q, or to Q cos(theta) with FLAG_COS_DISTRIBUTION)
// as an alias table in whole units (see SectorEntry), so a sample costs one
// read instead of a CDF search.

#include "shared.h"
#include "atomics.glsl"
#include "sampling.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

#include "grid.glsl"

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
layout(std430, set = 0, binding = B_VOLUME_SUMS) writeonly buffer VolumeSums { vec4 volume_sums[]; };
layout(std430, set = 0, binding = B_MIX_GRAD) buffer MixGrad { TALLY mix_grad[]; };
layout(std430, set = 0, binding = B_MIX_STATE) buffer MixState { vec4 mix_state[]; };

// Volume v's share of BSDF sampling in the mixture: guide_epsilon, or with
// FLAG_LEARN_MIX the sigmoid of a logit that starts at guide_epsilon's and
// takes an Adam step (state: logit, moments, steps) down the gradient the
// pass's paths tallied for v (sarsa.glsl) after a pass that learned.
float bsdf_share(uint v) {
    if ((params.flags & FLAG_LEARN_MIX) == 0u) {
        return params.guide_epsilon;
    }
    vec4 s = mix_state[v];
    if (s.w == 0.0) {
        s.x = log(params.guide_epsilon / (1.0 - params.guide_epsilon));
    }
    float pos = TALLY_VALUE(mix_grad[2u * v]);
    float neg = TALLY_VALUE(mix_grad[2u * v + 1u]);
    if (pos + neg > 0.0) {
        float g = pos - neg;
        mix_grad[2u * v] = TALLY_ZERO;
        mix_grad[2u * v + 1u] = TALLY_ZERO;
        s.w += 1.0;
        s.y = 0.9 * s.y + 0.1 * g;
        s.z = 0.999 * s.z + 0.001 * g * g;
        float m = s.y / (1.0 - pow(0.9, s.w));
        float r = s.z / (1.0 - pow(0.999, s.w));
        float step = r > 0.0 ? m / sqrt(r) : 0.0;
        s.x = clamp(s.x - MIX_LEARNING_RATE * step, -MIX_LOGIT_BOUND, MIX_LOGIT_BOUND);
    }
    mix_state[v] = s;
    return 1.0 / (1.0 + exp(-s.x));
}

// The working column of sector k while the table is built: units kept
// (up to W while a column is tall) and alias.
uint kept(uint i) {
    return sectors[i].column & 0xffffu;
}

void set_column(uint i, uint units, uint alias) {
    sectors[i].column = units | (alias << 16);
}

// Sector i's weight in its volume's distribution, from its Q (at least 0)
// and cos(theta): Q, or Q cos(theta) with FLAG_COS_DISTRIBUTION; with NEE,
// Q less the share NEE carries, as scattering should find what NEE does not.
float distribution_weight(uint i, float q, float cos_k) {
    float qs = (params.flags & FLAG_NEE) != 0u ? max(q - q_direct[i], 0.0) : q;
    return (params.flags & FLAG_COS_DISTRIBUTION) != 0u ? qs * cos_k : qs;
}

// First index from `from` on whose column is short of (or, with `large`, at
// least) one column's worth c, n if none.
uint next_column(uint base, uint from, uint n, uint c, bool large) {
    while (from < n && (kept(base + from) >= c) != large) {
        ++from;
    }
    return from;
}

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= params.volume_count) {
        return;
    }
    uint a = grid_a();
    uint b = grid_b();
    uint n = sector_count();
    // Units per column and in all.
    uint c = sector_column_units();
    uint units = n * c;
    uint base = v * n;
    bool learned = (params.flags & FLAG_LEARN) != 0u;
    float weighted = 0.0;
    float best = 0.0;
    float total = 0.0;
    for (uint k = 0u; k < n; ++k) {
        if (learned) {
            fold(base + k);
        }
        float cos_k = sector_cos(k, a, b);
        float q = max(q_values[base + k], 0.0);
        weighted += q * cos_k;
        best = max(best, q * cos_k);
        total += distribution_weight(base + k, q, cos_k);
    }
    bool max_target = (params.flags & FLAG_MAX_TARGET) != 0u;
    volume_sums[v] = vec4(max_target ? best : weighted * 2.0 * PI / float(n), total, bsdf_share(v), 0.0);
    // Whole units: sector k gets the units between the floors of its
    // running sum's start and end (scaled to W), the last end being W, so
    // the weights add up to W exactly (the last sector takes what rounding
    // left) and a zero weight stays zero. An all-zero volume samples
    // sectors uniformly.
    float scale = total > 0.0 ? float(units) / total : 0.0;
    float running = 0.0;
    uint start = 0u;
    for (uint k = 0u; k < n; ++k) {
        uint w = c;
        if (total > 0.0) {
            running += distribution_weight(base + k, max(q_values[base + k], 0.0), sector_cos(k, a, b));
            uint end = k + 1u == n ? units : min(uint(running * scale), units);
            w = end - start;
            start = end;
        }
        sectors[base + k].weights = w;
        set_column(base + k, w, k);
    }

    // Vose's alias construction as one sweep without work lists: short
    // columns are filled in index order, each from the current tall column l,
    // which moves on once it has become short itself. A column that becomes
    // short behind the sweep is filled next; one ahead of it, when reached.
    // In whole units every column ends with exactly c.
    uint s = next_column(base, 0u, n, c, false);
    uint l = next_column(base, 0u, n, c, true);
    uint short_column = s;
    while (short_column < n && l < n) {
        uint missing = c - kept(base + short_column);
        set_column(base + short_column, kept(base + short_column), l);
        uint left = kept(base + l) - missing;
        set_column(base + l, left, l);
        if (left < c) {
            uint now_short = l;
            l = next_column(base, l + 1u, n, c, true);
            if (now_short < s) {
                short_column = now_short;
                continue;
            }
        }
        s = next_column(base, s + 1u, n, c, false);
        short_column = s;
    }
    for (uint k = 0u; k < n; ++k) {
        uint alias = sectors[base + k].column >> 16;
        uint w = sectors[base + k].weights & 0xffffu;
        sectors[base + k].weights = w | ((sectors[base + alias].weights & 0xffffu) << 16);
    }
}
