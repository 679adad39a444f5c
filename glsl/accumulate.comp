#version 460
// Adds each pixel's path samples of the dispatch to the running sums and
// totals each sample pass's stats into that pass's slot.

#include "shared.h"

layout(local_size_x = TILE_X, local_size_y = TILE_Y) in;

layout(push_constant) uniform Push { PassParams params; };
layout(std430, set = 0, binding = B_SAMPLES) readonly buffer Samples { PathSample samples[]; };
layout(std430, set = 0, binding = B_ACCUM) buffer Accums { Accum accum[]; };
layout(std430, set = 0, binding = B_STATS) buffer Stats { PassStats pass_stats[]; };

// One global atomic per counter per workgroup instead of one per pixel.
shared uint s_paths;
shared uint s_zero;
shared uint s_length;
shared uint s_rays;
shared uint s_nan;
shared uint s_td_count;
// Float sums reduce through an array: shared float atomics are optional.
shared float s_td[TILE_X * TILE_Y];

void main() {
    uvec2 pixel = gl_GlobalInvocationID.xy;
    bool inside = pixel.x < params.width && pixel.y < params.height;
    uint index = pixel.y * params.width + pixel.x;
    uint pixels = params.width * params.height;
    // The trace pass wrote sample s of this dispatch at s * pixels + index.
    uint count = max(params.item_count, 1u);
    for (uint s = 0u; s < count; ++s) {
        if (gl_LocalInvocationIndex == 0u) {
            s_paths = 0u;
            s_zero = 0u;
            s_length = 0u;
            s_rays = 0u;
            s_nan = 0u;
            s_td_count = 0u;
        }
        s_td[gl_LocalInvocationIndex] = 0.0;
        barrier();

        if (inside) {
            PathSample ps = samples[s * pixels + index];
            bool bad = any(isnan(ps.radiance)) || any(isinf(ps.radiance));
            if (bad) {
                // Counted and left out rather than poisoning the pixel.
                atomicAdd(s_nan, 1u);
            } else {
                Accum a = accum[index];
                a.sum += vec4(ps.radiance, 1.0);
                a.sum_sq += vec4(ps.radiance * ps.radiance, 0.0);
                accum[index] = a;
                if ((ps.radiance.r + ps.radiance.g + ps.radiance.b) / 3.0 < 1e-4) {
                    atomicAdd(s_zero, 1u);
                }
            }
            atomicAdd(s_paths, 1u);
            atomicAdd(s_length, ps.path_length);
            atomicAdd(s_rays, ps.rays);
            atomicAdd(s_td_count, ps.td_count);
            s_td[gl_LocalInvocationIndex] = ps.td_sq_sum;
        }
        barrier();
        for (uint width = (TILE_X * TILE_Y) / 2u; width > 0u; width /= 2u) {
            if (gl_LocalInvocationIndex < width) {
                s_td[gl_LocalInvocationIndex] += s_td[gl_LocalInvocationIndex + width];
            }
            barrier();
        }

        if (gl_LocalInvocationIndex == 0u) {
            uint slot = (params.pass_index + s) % MAX_BATCH;
            atomicAdd(pass_stats[slot].paths, s_paths);
            atomicAdd(pass_stats[slot].zero_paths, s_zero);
            atomicAdd(pass_stats[slot].length_sum, s_length);
            atomicAdd(pass_stats[slot].rays, s_rays);
            atomicAdd(pass_stats[slot].nan_paths, s_nan);
            atomicAdd(pass_stats[slot].td_count, s_td_count);
            if (s_td[0] != 0.0) {
                // One float add per workgroup, by compare-and-swap on its bits.
                uint seen = pass_stats[slot].td_sq_bits;
                while (true) {
                    uint found = atomicCompSwap(pass_stats[slot].td_sq_bits, seen, floatBitsToUint(uintBitsToFloat(seen) + s_td[0]));
                    if (found == seen) {
                        break;
                    }
                    seen = found;
                }
            }
        }
        // The counters are reset for the next sample only after they are read.
        barrier();
    }
}
