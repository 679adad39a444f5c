#version 460
// Per volume, after a pass that learned (FLAG_LEARN): folds the targets the
// pass accumulated into Q. With alpha = 1 / (1 + visits), Q is the running
// mean of its targets, so Q <- (Q N + sum) / (N + count); the share NEE
// carries likewise. Then, always, from each sector's Q blended with its
// volume's mean target as (N Q + m mean) / (N + m), m = Q_PRIOR_VISITS
// (Q as it is in a volume never visited): the irradiance-like sum the Sarsa target needs,
// (2 pi / n) sum_j Q_j cos(theta_j) (with FLAG_MAX_TARGET, which only Neural-Q
// sets, max_j Q_j cos(theta_j)), the total weight of its distribution
// (with P(k), it gives back Q(v, k) without reading Q), and the distribution over
// sectors (proportional to Q cos(theta), or to Q with FLAG_Q_DISTRIBUTION)
// as an alias table in whole units (see SectorEntry), so a sample costs one
// read instead of a CDF search. With FLAG_GUIDE_LIGHTS it likewise folds
// NEE's tries of each light and builds the volume's choice of light.

#include "shared.h"
#include "atomics.glsl"
#include "sampling.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

// False for a table nothing samples from (Neural-Q's running means of its
// targets): the update folds the pass's tallies and takes the share's step,
// and builds no distribution (lavapipe would run the code of a branch no
// invocation takes, so it is left out when the pipeline is built).
layout(constant_id = 0) const bool BUILD_TABLE = true;

#include "grid.glsl"

layout(std430, set = 0, binding = B_Q) buffer QValues { float q_values[]; };
layout(std430, set = 0, binding = B_Q_DIRECT) buffer QDirect { float q_direct[]; };
layout(std430, set = 0, binding = B_VISITS_TOTAL) buffer VisitsTotal { uint visits_total[]; };
// The pass's tallies, as the trace kernel's atomics wrote them (float
// atomics and the CAS fallback write the same bits), read as texels: lavapipe
// reads a texel of 8 lanes with one gather, a storage buffer word by word and
// lane by lane. The host zeroes them after this pass (a fill).
WORDS(target_sum_texels, B_SUM)
WORDS(direct_sum_texels, B_DIRECT_SUM)
WORDS(visits_texels, B_VISITS)
WORDS(mix_grad_texels, B_MIX_GRAD)

// Tally i of a buffer of TALLY (two 32-bit words each as fixed point, else one).
#ifdef FIXED_ATOMICS
#define TALLY_AT(texels, i) tally_fixed(FETCH(texels, int((i) >> 1u)), (i) & 1u)
float tally_fixed(uvec4 texel, uint half_index) {
    uvec2 words = half_index != 0u ? texel.zw : texel.xy;
    return float(words.y) + float(words.x) / FIXED_ONE;
}
#else
#define TALLY_AT(texels, i) uintBitsToFloat(FETCH(texels, int((i) >> 2u))[(i) & 3u])
#endif

// Folds cell i's tallies of the pass into its running means q and qd:
// Q <- (Q N + sum) / (N + count), and writes them.
void fold(uint i, inout float q, inout float qd) {
    uint count = FETCH(visits_texels, int(i >> 2u))[i & 3u];
    if (count == 0u) {
        return;
    }
    uint seen = visits_total[i];
    q = (q * float(seen) + TALLY_AT(target_sum_texels, i)) / float(seen + count);
    qd = (qd * float(seen) + TALLY_AT(direct_sum_texels, i)) / float(seen + count);
    q_values[i] = q;
    q_direct[i] = qd;
    visits_total[i] = seen + count;
}
layout(std430, set = 0, binding = B_SECTORS) buffer Sectors { SectorEntry sectors[]; };
layout(std430, set = 0, binding = B_VOLUME_SUMS) writeonly buffer VolumeSums { vec4 volume_sums[]; };
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
    float pos = TALLY_AT(mix_grad_texels, 2u * v);
    float neg = TALLY_AT(mix_grad_texels, 2u * v + 1u);
    if (pos + neg > 0.0) {
        float g = pos - neg;
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

// A sector's weight in its volume's distribution, from its Q (at least 0),
// the share of Q that NEE carries, qd, and cos(theta): Q, or Q cos(theta)
// unless FLAG_Q_DISTRIBUTION; with NEE, Q less qd, as scattering should
// find what NEE does not.
float distribution_weight(float q, float qd, float cos_k) {
    float qs = (params.flags & FLAG_NEE) != 0u ? max(q - qd, 0.0) : q;
    return !EXPERIMENT(FLAG_Q_DISTRIBUTION) ? qs * cos_k : qs;
}

// First index from `from` on whose column is short of (or, with `large`, at
// least) one column's worth c, n if none.
uint next_column(uint base, uint from, uint n, uint c, bool large) {
    while (from < n && (kept(base + from) >= c) != large) {
        ++from;
    }
    return from;
}

// Turns the float weights waiting in entries base .. base + n - 1 (in
// `weights`), which add up to `total`, into an alias table in whole units.
void build_alias(uint base, uint n, float total) {
    uint c = column_units(n);
    uint units = n * c;
    // Whole units: entry k gets the units between the floors of its
    // running sum's start and end (scaled to W), the last end being W, so
    // the weights add up to W exactly (the last entry takes what rounding
    // left) and a zero weight stays zero. An all-zero table samples
    // its entries uniformly.
    float scale = total > 0.0 ? float(units) / total : 0.0;
    float running = 0.0;
    uint start = 0u;
    for (uint k = 0u; k < n; ++k) {
        uint w = c;
        if (total > 0.0) {
            running += uintBitsToFloat(sectors[base + k].weights);
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

// NEE's choice of light (FLAG_GUIDE_LIGHTS), per (volume, light): the
// pass's tallies (texels, as above), the running mean of what a try of the
// light brought and its count, and the light's share of emitted power.
WORDS(light_sum_texels, B_LIGHT_SUM)
WORDS(light_tries_texels, B_LIGHT_TRIES)
layout(std430, set = 0, binding = B_LIGHT_MEAN) buffer LightMean { float light_mean[]; };
layout(std430, set = 0, binding = B_LIGHT_SEEN) buffer LightSeen { uint light_seen[]; };
layout(std430, set = 0, binding = B_LIGHT_POWER) readonly buffer LightPower { float light_power[]; };

// Volume v's choice of light: after a pass that learned, its tries folded
// into the running means; then its alias table, LIGHT_POWER_SHARE by
// emitted power (so every light keeps being tried) and the rest in
// proportion to what each light brought, once the volume has had
// LIGHT_MIN_TRIES tries. v = volume_count builds the row by power alone
// that vertices without a volume use.
void build_light_choice(uint v, bool learned) {
    uint n = params.light_count;
    uint base = v * n;
    bool own = v < params.volume_count;
    float brought = 0.0;
    uint tries = 0u;
    for (uint l = 0u; own && l < n; ++l) {
        float mean = light_mean[base + l];
        uint seen = light_seen[base + l];
        uint count = learned ? FETCH(light_tries_texels, int((base + l) >> 2u))[(base + l) & 3u] : 0u;
        if (count > 0u) {
            mean = (mean * float(seen) + TALLY_AT(light_sum_texels, base + l)) / float(seen + count);
            seen += count;
            light_mean[base + l] = mean;
            light_seen[base + l] = seen;
        }
        brought += mean;
        tries += seen;
    }
    if (!BUILD_TABLE) {
        return;
    }
    bool follows = own && tries >= LIGHT_MIN_TRIES && brought > 0.0;
    uint row = light_row(v);
    float total = 0.0;
    for (uint l = 0u; l < n; ++l) {
        float w = light_power[l];
        if (follows) {
            w = LIGHT_POWER_SHARE * w + (1.0 - LIGHT_POWER_SHARE) * light_mean[base + l] / brought;
        }
        total += w;
        sectors[row + l].weights = floatBitsToUint(w);
    }
    build_alias(row, n, total);
}

void main() {
    uint v = gl_GlobalInvocationID.x;
    bool learned = (params.flags & FLAG_LEARN) != 0u;
    if ((params.flags & FLAG_GUIDE_LIGHTS) != 0u && v <= params.volume_count) {
        build_light_choice(v, learned);
    }
    if (v >= params.volume_count) {
        return;
    }
    uint a = grid_a();
    uint b = grid_b();
    uint n = sector_count();
    uint base = v * n;
    float weighted = 0.0;
    float best = 0.0;
    float total = 0.0;
    // The volume's mean of every target it has had (and of NEE's share),
    // which a sector with few visits of its own leans on (Q_PRIOR_VISITS).
    float seen_all = 0.0;
    float q_all = 0.0;
    float qd_all = 0.0;
    for (uint k = 0u; k < n; ++k) {
        float q = q_values[base + k];
        float qd = q_direct[base + k];
        if (learned) {
            fold(base + k, q, qd);
        }
        float seen = float(visits_total[base + k]);
        seen_all += seen;
        q_all += seen * q;
        qd_all += seen * qd;
    }
    q_all /= max(seen_all, 1.0);
    qd_all /= max(seen_all, 1.0);
    // Each sector's weight waits in its table entry for the second sweep.
    for (uint k = 0u; k < n; ++k) {
        float q = q_values[base + k];
        float qd = q_direct[base + k];
        if (seen_all > 0.0) {
            float seen = float(visits_total[base + k]);
            float m = float(Q_PRIOR_VISITS);
            q = (q * seen + m * q_all) / (seen + m);
            qd = (qd * seen + m * qd_all) / (seen + m);
        }
        float cos_k = sector_cos(k, a, b);
        q = max(q, 0.0);
        weighted += q * cos_k;
        best = max(best, q * cos_k);
        float w = distribution_weight(q, qd, cos_k);
        total += w;
        if (BUILD_TABLE) {
            sectors[base + k].weights = floatBitsToUint(w);
        }
    }
    bool max_target = EXPERIMENT(FLAG_MAX_TARGET);
    volume_sums[v] = vec4(max_target ? best : weighted * 2.0 * PI / float(n), total, bsdf_share(v), 0.0);
    if (!BUILD_TABLE) {
        return;
    }
    build_alias(base, n, total);
}
