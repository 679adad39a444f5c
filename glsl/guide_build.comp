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
//
// Two variants, the same tables bit for bit. One invocation a volume walks
// its sectors (lavapipe: its SIMD lanes hold eight volumes). With
// WIDE_UPDATE, one workgroup a volume (GPUs: one invocation a volume leaves
// most of the device idle and reads each sector on its own): the lanes read,
// fold and write the sectors side by side, and lane 0 adds up and sweeps the
// alias table in workgroup memory, in the order one invocation does.

#include "shared.h"
#include "atomics.glsl"
#include "sampling.glsl"

layout(push_constant) uniform Push { PassParams params; };

// False for a table nothing samples from (Neural-Q's running means of its
// targets): the update folds the pass's tallies and takes the share's step,
// and builds no distribution (lavapipe would run the code of a branch no
// invocation takes, so it is left out when the pipeline is built).
layout(constant_id = 0) const bool BUILD_TABLE = true;

#ifdef WIDE_UPDATE
layout(local_size_x = WIDE_UPDATE_GROUP) in;
// Entries of the largest table a workgroup builds: max(sectors, lights).
layout(constant_id = 1) const uint WIDE_ENTRIES = 1u;
// A sector's visits, Q and NEE's share of it, then its Q cos(theta) (in
// wide_seen) while the sums are taken; the table's weights and columns
// while it is built.
shared float wide_seen[WIDE_ENTRIES];
shared float wide_q[WIDE_ENTRIES];
shared float wide_qd[WIDE_ENTRIES];
shared uint wide_weights[WIDE_ENTRIES];
shared uint wide_columns[WIDE_ENTRIES];
shared vec3 wide_means;
// A table under construction: its entries in workgroup memory from 0.
#define ENTRY_WEIGHTS(i) wide_weights[i]
#define ENTRY_COLUMN(i) wide_columns[i]
#define TABLE_START(row) 0u
#else
layout(local_size_x = LINEAR_GROUP) in;
// A table under construction: in place in the sector tables.
#define ENTRY_WEIGHTS(i) sectors[i].weights
#define ENTRY_COLUMN(i) sectors[i].column
#define TABLE_START(row) (row)
#endif

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
    return ENTRY_COLUMN(i) & 0xffffu;
}

void set_column(uint i, uint units, uint alias) {
    ENTRY_COLUMN(i) = units | (alias << 16);
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
            running += uintBitsToFloat(ENTRY_WEIGHTS(base + k));
            uint end = k + 1u == n ? units : min(uint(running * scale), units);
            w = end - start;
            start = end;
        }
        ENTRY_WEIGHTS(base + k) = w;
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
        uint alias = ENTRY_COLUMN(base + k) >> 16;
        uint w = ENTRY_WEIGHTS(base + k) & 0xffffu;
        ENTRY_WEIGHTS(base + k) = w | ((ENTRY_WEIGHTS(base + alias) & 0xffffu) << 16);
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
    uint n = light_groups();
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
    uint table = TABLE_START(row);
    float total = 0.0;
    for (uint l = 0u; l < n; ++l) {
        float w = light_power[l];
        if (follows) {
            w = LIGHT_POWER_SHARE * w + (1.0 - LIGHT_POWER_SHARE) * light_mean[base + l] / brought;
        }
        total += w;
        ENTRY_WEIGHTS(table + l) = floatBitsToUint(w);
    }
    build_alias(table, n, total);
#ifdef WIDE_UPDATE
    for (uint l = 0u; l < n; ++l) {
        sectors[row + l] = SectorEntry(wide_weights[l], wide_columns[l]);
    }
#endif
}

// Adds sector k's visits (seen), and its Q and NEE's share weighted by
// them, to sums (precise: both variants add the same bits in sector order).
void add_visits(inout vec3 sums, float seen, float q, float qd) {
    precise vec3 s = sums;
    s.x += seen;
    s.y += seen * q;
    s.z += seen * qd;
    sums = s;
}

// Volume v's sums of its sectors' visits, Q and NEE's share (add_visits),
// as the volume's mean of every target it has had (and of NEE's share),
// which a sector with few visits of its own leans on (Q_PRIOR_VISITS):
// (visits, mean Q, mean share).
vec3 volume_means(vec3 sums) {
    return vec3(sums.x, sums.y / max(sums.x, 1.0), sums.z / max(sums.x, 1.0));
}

// Sector k's Q blended with its volume's means (Q_PRIOR_VISITS), at least
// 0, times cos(theta), and its weight in the distribution.
vec2 sector_weight(uint base, uint k, vec3 means) {
    precise float q = q_values[base + k];
    precise float qd = q_direct[base + k];
    if (means.x > 0.0) {
        float seen = float(visits_total[base + k]);
        float m = float(Q_PRIOR_VISITS);
        q = (q * seen + m * means.y) / (seen + m);
        qd = (qd * seen + m * means.z) / (seen + m);
    }
    float cos_k = sector_cos(k, grid_a(), grid_b());
    q = max(q, 0.0);
    precise float qc = q * cos_k;
    return vec2(qc, distribution_weight(q, qd, cos_k));
}

// Adds a sector's Q cos(theta) and weight to sums: (sum, max, total).
void add_weight(inout vec3 sums, vec2 w) {
    precise vec3 s = sums;
    s.x += w.x;
    s.y = max(s.y, w.x);
    s.z += w.y;
    sums = s;
}

// What the trace kernels read of volume v besides its table: the Sarsa
// target's sum, (2 pi / n) sum_j Q_j cos(theta_j) (with FLAG_MAX_TARGET,
// which only Neural-Q sets, max_j Q_j cos(theta_j)), the table's total
// weight and the share of BSDF sampling.
void write_volume_sums(uint v, vec3 sums) {
    bool max_target = EXPERIMENT(FLAG_MAX_TARGET);
    volume_sums[v] = vec4(max_target ? sums.y : sums.x * 2.0 * PI / float(sector_count()), sums.z, bsdf_share(v), 0.0);
}

#ifndef WIDE_UPDATE
void main() {
    uint v = gl_GlobalInvocationID.x;
    bool learned = (params.flags & FLAG_LEARN) != 0u;
    if ((params.flags & FLAG_GUIDE_LIGHTS) != 0u && v <= params.volume_count) {
        build_light_choice(v, learned);
    }
    if (v >= params.volume_count) {
        return;
    }
    uint n = sector_count();
    uint base = v * n;
    vec3 sums = vec3(0.0);
    for (uint k = 0u; k < n; ++k) {
        float q = q_values[base + k];
        float qd = q_direct[base + k];
        if (learned) {
            fold(base + k, q, qd);
        }
        add_visits(sums, float(visits_total[base + k]), q, qd);
    }
    vec3 means = volume_means(sums);
    // Each sector's weight waits in its table entry for the alias sweep.
    vec3 weights = vec3(0.0);
    for (uint k = 0u; k < n; ++k) {
        vec2 w = sector_weight(base, k, means);
        add_weight(weights, w);
        if (BUILD_TABLE) {
            sectors[base + k].weights = floatBitsToUint(w.y);
        }
    }
    write_volume_sums(v, weights);
    if (BUILD_TABLE) {
        build_alias(base, n, weights.z);
    }
}
#else
void main() {
    // Workgroups past the device's largest x count go on in y.
    uint v = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint lane = gl_LocalInvocationID.x;
    bool learned = (params.flags & FLAG_LEARN) != 0u;
    if (lane == 0u && (params.flags & FLAG_GUIDE_LIGHTS) != 0u && v <= params.volume_count) {
        build_light_choice(v, learned);
    }
    // The same for the whole workgroup, so no lane misses a barrier.
    if (v >= params.volume_count) {
        return;
    }
    uint n = sector_count();
    uint base = v * n;
    for (uint k = lane; k < n; k += WIDE_UPDATE_GROUP) {
        float q = q_values[base + k];
        float qd = q_direct[base + k];
        if (learned) {
            fold(base + k, q, qd);
        }
        wide_seen[k] = float(visits_total[base + k]);
        wide_q[k] = q;
        wide_qd[k] = qd;
    }
    barrier();
    if (lane == 0u) {
        vec3 sums = vec3(0.0);
        for (uint k = 0u; k < n; ++k) {
            add_visits(sums, wide_seen[k], wide_q[k], wide_qd[k]);
        }
        wide_means = volume_means(sums);
    }
    barrier();
    vec3 means = wide_means;
    for (uint k = lane; k < n; k += WIDE_UPDATE_GROUP) {
        vec2 w = sector_weight(base, k, means);
        wide_seen[k] = w.x;
        wide_weights[k] = floatBitsToUint(w.y);
    }
    barrier();
    if (lane == 0u) {
        vec3 weights = vec3(0.0);
        for (uint k = 0u; k < n; ++k) {
            add_weight(weights, vec2(wide_seen[k], uintBitsToFloat(wide_weights[k])));
        }
        write_volume_sums(v, weights);
        if (BUILD_TABLE) {
            build_alias(0u, n, weights.z);
        }
    }
    barrier();
    for (uint k = lane; BUILD_TABLE && k < n; k += WIDE_UPDATE_GROUP) {
        sectors[base + k] = SectorEntry(wide_weights[k], wide_columns[k]);
    }
}
#endif
