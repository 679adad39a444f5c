// Learned guides: radiance-volume lookup, sector sampling and the Expected
// Sarsa update. Needs shared.h, sampling.glsl and the `params` push constants.
#ifndef QTRACE_GUIDE_GLSL
#define QTRACE_GUIDE_GLSL

#include "grid.glsl"

#ifdef FLOAT_ATOMICS
#extension GL_EXT_shader_atomic_float : require
#endif

// The tables the trace kernel only reads are uniform texel buffers of raw
// words (one vector gather per read on lavapipe; see scene.glsl).
layout(set = 0, binding = B_SECTORS) uniform usamplerBuffer sector_texels; // 1 per SectorEntry
// Per volume: (irradiance (2 pi / n) sum_j Q_j cos(theta_j), total weight of
// its sector distribution), two volumes per texel; see guide_build.comp.
layout(set = 0, binding = B_VOLUME_SUMS) uniform usamplerBuffer volume_sum_texels;
#ifdef FLOAT_ATOMICS
layout(std430, set = 0, binding = B_SUM) buffer TargetSums { float target_sum[]; };
#else
layout(std430, set = 0, binding = B_SUM) buffer TargetSums { uint target_sum_bits[]; };
#endif
layout(std430, set = 0, binding = B_VISITS) buffer Visits { uint visits[]; };
// With NEE: per (volume, sector), the part of this pass's emitter targets
// that NEE already carries (Le times one minus the scattering MIS weight).
#ifdef FLOAT_ATOMICS
layout(std430, set = 0, binding = B_DIRECT_SUM) buffer DirectSums { float direct_sum[]; };
#else
layout(std430, set = 0, binding = B_DIRECT_SUM) buffer DirectSums { uint direct_sum_bits[]; };
#endif
layout(set = 0, binding = B_Q) uniform usamplerBuffer q_texels; // 4 Q per texel
// The per-triangle lookup tables of src/guide/lookup.rs: cells (uvec2, two
// per texel) and list entries (volume position, volume index bits).
layout(set = 0, binding = B_LOOKUP_CELLS) uniform usamplerBuffer lookup_cell_texels;
layout(set = 0, binding = B_LOOKUP_ITEMS) uniform usamplerBuffer lookup_item_texels;

SectorEntry load_sector(uint i) {
    uvec4 t = texelFetch(sector_texels, int(i));
    return SectorEntry(uintBitsToFloat(t.x), t.y, uintBitsToFloat(t.z), uintBitsToFloat(t.w));
}

float load_q(uint i) {
    return uintBitsToFloat(texelFetch(q_texels, int(i >> 2u))[i & 3u]);
}


// Exact nearest volume to p, a point shading the front (or back) side of
// triangle `tri`, among the volumes facing that side; NO_VOLUME if none.
// The triangle or its cell holds the answer, or a short list that does.
uint nearest_volume(Triangle tri, vec3 p, bool front) {
    uvec4 t = tri.lookup;
    if (t.y == 0u) {
        return front ? t.z : t.w;
    }
    uint nu = t.y & 0xffffu;
    uint nv = t.y >> 16;
    uint cell = t.x + (front ? 0u : nu * nv);
    if (nu * nv > 1u) {
        // Barycentric coordinates of p: its offset is along the triangle's
        // normal, so it drops out. (Triangles with a small angle at v0, where
        // these lose precision, have one cell; see src/guide/lookup.rs.)
        vec3 q = p - tri.v0;
        float d00 = dot(tri.e1, tri.e1);
        float d01 = dot(tri.e1, tri.e2);
        float d11 = dot(tri.e2, tri.e2);
        float d20 = dot(q, tri.e1);
        float d21 = dot(q, tri.e2);
        float inv = 1.0 / (d00 * d11 - d01 * d01);
        vec2 uv = vec2(d11 * d20 - d01 * d21, d00 * d21 - d01 * d20) * inv;
        uvec2 c = uvec2(clamp(uv * vec2(nu, nv), vec2(0.0), vec2(nu - 1u, nv - 1u)));
        cell += c.x + nu * c.y;
    }
    uvec4 pair = texelFetch(lookup_cell_texels, int(cell >> 1u));
    uvec2 entry = (cell & 1u) == 0u ? pair.xy : pair.zw;
    if (entry.y == 0u) {
        return entry.x;
    }
    uint best = NO_VOLUME;
    float best_d2 = FAR;
    for (uint i = entry.x; i < entry.x + entry.y; ++i) {
        vec4 item = uintBitsToFloat(texelFetch(lookup_item_texels, int(i)));
        vec3 d = item.xyz - p;
        float d2 = dot(d, d);
        if (d2 < best_d2) {
            best = floatBitsToUint(item.w);
            best_d2 = d2;
        }
    }
    return best;
}

// P(sector k) of volume v's distribution.
float sector_probability(uint v, uint k) {
    return load_sector(v * sector_count() + k).p;
}

// Solid-angle pdf of the mixture of cosine and volume v's distribution.
float mixture_pdf(uint v, float p_sector, float cos_theta) {
    float eps = v == NO_VOLUME ? 1.0 : params.guide_epsilon;
    return mixture_density(eps, p_sector, sector_count(), cos_theta);
}

float guide_pdf(uint v, vec3 local) {
    float p = v == NO_VOLUME ? 0.0 : sector_probability(v, hemisphere_sector(local, grid_a(), grid_b()));
    return mixture_pdf(v, p, local.z);
}

// A local direction from the mixture, the sector it lies in and that
// sector's probability; u = three uniform numbers.
vec3 guide_sample(uint v, vec3 u, out uint sector, out float p_sector) {
    bool guided = v != NO_VOLUME && u.z >= params.guide_epsilon;
    uint n = sector_count();
    uint k = 0u;
    p_sector = 0.0;
    if (guided) {
        // Alias method: u.z, rescaled to [0, n), picks a column; its fraction
        // decides between the column's sector and its alias.
        float x = (u.z - params.guide_epsilon) / (1.0 - params.guide_epsilon) * float(n);
        k = min(uint(x), n - 1u);
        SectorEntry e = load_sector(v * n + k);
        bool keep = x - float(k) < e.threshold;
        k = keep ? k : e.alias;
        p_sector = keep ? e.p : e.p_alias;
    }
    vec3 local = mixture_direction(guided, k, u.xy, grid_a(), grid_b(), sector);
    if (!guided && v != NO_VOLUME) {
        p_sector = sector_probability(v, sector);
    }
    return local;
}

// A volume's sums, zero for NO_VOLUME.
vec2 volume_sums_of(uint v) {
    if (v == NO_VOLUME) {
        return vec2(0.0);
    }
    uvec4 pair = texelFetch(volume_sum_texels, int(v >> 1u));
    return uintBitsToFloat((v & 1u) == 0u ? pair.xy : pair.zw);
}

// Expected Sarsa target for a bounce that reached a surface y whose volume
// has sums `sums`: (2 pi / n) sum_j Q(vy, j) f_s cos(theta_j) = albedo / pi * irradiance.
float sarsa_surface_target(vec2 sums, float albedo) {
    return albedo * INV_PI * sums.x;
}

// Q(v, k) of the sampling table (clamped at 0, and with NEE less NEE's
// share), given back from P(k) = w_k / total with w_k = Q_k (cos theta_k for
// the Q cos distribution): no read of Q in the trace kernel.
float sector_q(vec2 sums, uint k, float p_sector) {
    float w = p_sector * sums.y;
    return (params.flags & FLAG_COS_DISTRIBUTION) != 0u ? w / sector_cos(k, grid_a(), grid_b()) : w;
}

#ifdef FLOAT_ATOMICS
#define ADD_FLOAT(tally, bits, value) atomicAdd(tally, value)
#else
// Compare-and-swap fallback for devices without float atomics: `bits` is the
// tally seen as uint.
#define ADD_FLOAT(tally, bits, value)                                       \
    {                                                                       \
        uint seen = bits;                                                   \
        while (true) {                                                      \
            uint wanted = floatBitsToUint(uintBitsToFloat(seen) + (value)); \
            uint found = atomicCompSwap(bits, seen, wanted);                \
            if (found == seen) {                                            \
                break;                                                      \
            }                                                               \
            seen = found;                                                   \
        }                                                                   \
    }
#endif

// Adds one target for (v, k), whose Q was q; the fold pass turns sums and
// counts into means. Returns the squared temporal-difference error.
float sarsa_record(uint v, uint k, float target, float q) {
    uint index = v * sector_count() + k;
    ADD_FLOAT(target_sum[index], target_sum_bits[index], target);
    atomicAdd(visits[index], 1u);
    float td = target - q;
    return td * td;
}

// With NEE: records the part of an emitter target for (v, k) that NEE
// already carries, so sampling can leave it to NEE.
void sarsa_record_direct(uint v, uint k, float excess) {
    uint index = v * sector_count() + k;
    ADD_FLOAT(direct_sum[index], direct_sum_bits[index], excess);
}

#endif
