#version 460
// Adds each pixel's path samples of the dispatch to its running sums and
// totals each sample pass's stats into that pass's slot.
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require

#include "shared.h"
#include "atomics.glsl"

layout(local_size_x = TILE_X, local_size_y = TILE_Y) in;
// A race's passes (src/render/race.rs) measure their deviation against
// B_RACE_REF; a constant, so that other passes do not pay for its reads.
layout(constant_id = 0) const bool RACE = false;

layout(push_constant) uniform Push { PassParams params; };
// Read as texels (2 per PathSample): one vector gather each on lavapipe.
WORDS(sample_texels, B_SAMPLES)
layout(std430, set = 0, binding = B_ACCUM) buffer Accums { Accum accum[]; };
// PassStats as words: paths, zero_paths, length_sum, rays, nan_paths,
// td_count, td_sq_bits, dev_bits, then a race's lap_bits[4]; STATS_COPIES
// copies of MAX_BATCH slots.
layout(std430, set = 0, binding = B_STATS) buffer Stats { uint stats_words[]; };
layout(std430, set = 0, binding = B_RACE_REF) readonly buffer RaceRef { Accum race_ref[]; };

#define COUNTERS 6
// Float totals after the counters: td_sq, dev, and in a race lap's four.
#define FLOATS 6
// Subgroups hold at least 4 invocations.
#define MAX_SUBGROUPS (TILE_X * TILE_Y / 4)
// Each subgroup's totals per sample of the dispatch, summed once at the end:
// no barrier or shared atomic per sample.
shared uint s_counts[MAX_BATCH][MAX_SUBGROUPS][COUNTERS];
shared float s_f[MAX_BATCH][MAX_SUBGROUPS][FLOATS];

void main() {
    uvec2 pixel = gl_GlobalInvocationID.xy;
    bool inside = pixel.x < params.width && pixel.y < params.height;
    uint index = pixel.y * params.width + pixel.x;
    uint pixels = params.width * params.height;
    // The trace pass wrote sample s of this dispatch at s * pixels + index.
    uint count = clamp(params.item_count, 1u, MAX_BATCH);
    // The pixel's sums stay in registers over the dispatch's samples.
    Accum a = Accum(vec4(0.0), vec4(0.0));
    // Deviations are measured against the pixel's mean so far, or in a race
    // against its mean when the race began, so that no lap's reference
    // holds another lap's sample.
    vec4 ref = vec4(0.0);
    const bool race = RACE;
    if (inside) {
        a = accum[index];
        ref = race ? race_ref[index].sum : a.sum;
    }
    for (uint s = 0u; s < count; ++s) {
        uint c[COUNTERS] = uint[COUNTERS](0u, 0u, 0u, 0u, 0u, 0u);
        float td = 0.0;
        float dev = 0.0;
        // In a race (src/render/race.rs, "missed light"): the sample's value
        // (the mean of its channels), its square, its pixel's reference
        // mean's value and a bound on that mean's variance.
        vec4 lap = vec4(0.0);
        if (inside) {
            uvec4 t0 = FETCH(sample_texels, int(2u * (s * pixels + index)));
            uvec4 t1 = FETCH(sample_texels, int(2u * (s * pixels + index) + 1u));
            vec3 radiance = uintBitsToFloat(t0.xyz);
            if (any(isnan(radiance)) || any(isinf(radiance))) {
                // Counted and left out rather than poisoning the pixel.
                c[4] = 1u;
            } else {
                // Squared deviation from the pixel's mean so far, relative as
                // relMSE weighs it: the race between guided and plain passes
                // compares these (see src/render/race.rs).
                if (ref.w > 0.0) {
                    vec3 mean = ref.rgb / ref.w;
                    vec3 d = radiance - mean;
                    vec3 dd = d * d;
                    // In a race, less the reference mean's own variance
                    // (the sample variance over its count), which would
                    // otherwise add alike to every lap and hide their ratio.
                    if (race) {
                        lap.z = dot(mean, vec3(1.0 / 3.0));
                        lap.w = lap.z * lap.z;
                    }
                    if (race && ref.w > 1.0) {
                        vec3 sq = race_ref[index].sum_sq.rgb;
                        vec3 mean_variance = max(sq - ref.w * mean * mean, 0.0) / (ref.w * (ref.w - 1.0));
                        dd -= mean_variance;
                        // The channels' mean varies at most as their
                        // deviations' mean squared.
                        lap.w = dot(sqrt(mean_variance), vec3(1.0 / 3.0));
                        lap.w *= lap.w;
                    }
                    dev = dot(dd / (mean * mean + 0.01), vec3(1.0 / 3.0));
                }
                lap.x = race ? dot(radiance, vec3(1.0 / 3.0)) : 0.0;
                lap.y = lap.x * lap.x;
                a.sum += vec4(radiance, 1.0);
                ref = race ? ref : a.sum;
                a.sum_sq += vec4(radiance * radiance, 0.0);
                // (A filter with negative lobes makes some samples negative.)
                c[1] = abs(radiance.r + radiance.g + radiance.b) / 3.0 < 1e-4 ? 1u : 0u;
            }
            c[0] = 1u;
            c[2] = t0.w & ((1u << PATH_RAYS_SHIFT) - 1u);
            c[3] = (t0.w & ~PATH_LEARNED) >> PATH_RAYS_SHIFT;
            bool learned = (t0.w & PATH_LEARNED) != 0u;
            c[5] = learned ? t1.x : 0u;
            td = learned ? uintBitsToFloat(t1.y) : 0.0;
        }
        for (uint k = 0u; k < COUNTERS; ++k) {
            c[k] = subgroupAdd(c[k]);
        }
        td = subgroupAdd(td);
        dev = subgroupAdd(dev);
        lap = race ? subgroupAdd(lap) : lap;
        if (subgroupElect()) {
            for (uint k = 0u; k < COUNTERS; ++k) {
                s_counts[s][gl_SubgroupID][k] = c[k];
            }
            s_f[s][gl_SubgroupID][0] = td;
            s_f[s][gl_SubgroupID][1] = dev;
            for (uint k = 0u; k < 4u; ++k) {
                s_f[s][gl_SubgroupID][2u + k] = lap[k];
            }
        }
    }
    if (inside) {
        accum[index] = a;
    }
    barrier();

    // One invocation per (sample, counter): sums the subgroups, then one
    // global atomic per workgroup, into the workgroup's copy of the stats.
    uint copy = (gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) % STATS_COPIES;
    for (uint task = gl_LocalInvocationIndex; task < count * (COUNTERS + FLOATS); task += TILE_X * TILE_Y) {
        uint s = task / (COUNTERS + FLOATS);
        uint k = task % (COUNTERS + FLOATS);
        uint word = (copy * MAX_BATCH + (params.pass_index + s) % MAX_BATCH) * (SIZEOF_PASS_STATS / 4u) + k;
        if (k < COUNTERS) {
            uint sum = 0u;
            for (uint g = 0u; g < gl_NumSubgroups; ++g) {
                sum += s_counts[s][g][k];
            }
            atomicAdd(stats_words[word], sum);
        } else {
            float sum = 0.0;
            for (uint g = 0u; g < gl_NumSubgroups; ++g) {
                sum += s_f[s][g][k - COUNTERS];
            }
            if (sum != 0.0) {
                CAS_ADD_FLOAT(stats_words[word], sum);
            }
        }
    }
}
